# System libraries, all from Debian 12 packages (scripts/install-deps.sh installs them).
# Each is found once here and used through its imported target; a folder links only what it needs.
find_package(PkgConfig REQUIRED)
pkg_check_modules(ARAVIS REQUIRED IMPORTED_TARGET aravis-0.8)
pkg_check_modules(LIBMODBUS REQUIRED IMPORTED_TARGET libmodbus)
pkg_check_modules(LIBUSB REQUIRED IMPORTED_TARGET libusb-1.0)
pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)  # goniod's API and gonioctl
pkg_check_modules(LIBSYSTEMD REQUIRED IMPORTED_TARGET libsystemd)  # goniod's readiness (sd_notify)
find_package(OpenCV REQUIRED COMPONENTS core imgproc imgcodecs)
find_package(Ceres REQUIRED)
find_package(SQLite3 REQUIRED)
find_package(tomlplusplus REQUIRED)
find_package(nlohmann_json REQUIRED)
find_package(CLI11 REQUIRED)
find_package(spdlog REQUIRED)
find_package(Boost REQUIRED)  # header-only parts: math special functions and quadrature
if(GONIO_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(GONIO_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
