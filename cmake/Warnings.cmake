# Warnings for the project's own targets (not for third-party headers, which come in as SYSTEM).
# Not -Wnull-dereference: with GCC 12 at -O2 it reports false positives inside libstdc++'s
# std::string, which -Werror would turn into build failures.
add_library(gonio_warnings INTERFACE)
add_library(gonio::warnings ALIAS gonio_warnings)
target_compile_options(gonio_warnings INTERFACE
  -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor -Wcast-align
  -Wdouble-promotion -Wimplicit-fallthrough
  $<$<BOOL:${GONIO_WERROR}>:-Werror>)

if(GONIO_FUZZ AND NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  message(FATAL_ERROR "GONIO_FUZZ needs clang (libFuzzer): -DCMAKE_CXX_COMPILER=clang++")
endif()
if(GONIO_SANITIZE OR GONIO_FUZZ)
  # -fno-sanitize-recover: a UBSan finding fails the test instead of printing and going on.
  add_compile_options(-fsanitize=address,undefined -fno-sanitize-recover=all
                      -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()
if(GONIO_FUZZ)
  # Every library instrumented for libFuzzer's coverage; the fuzz targets add the fuzzer's main.
  # Beside the test suite (GONIO_SANITIZE too, scripts/sanitize.sh) the coverage is the edge
  # counters alone: comparison tracing would slow every test for the fuzzer's sake.
  if(GONIO_SANITIZE)
    add_compile_options(-fsanitize-coverage=inline-8bit-counters,pc-table)
  else()
    add_compile_options(-fsanitize=fuzzer-no-link)
  endif()
endif()
