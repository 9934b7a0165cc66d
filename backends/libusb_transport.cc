#include "backends/libusb_transport.h"

#include <libusb.h>

#include <cstdio>

namespace gonio::backends {

namespace usbtmc_request = devices::usbtmc_request;

namespace {

std::string IdText(const UsbDeviceId& id) {
  char b[32];
  std::snprintf(b, sizeof b, "%04x:%04x", id.vendor_id, id.product_id);
  return std::string(b) + (id.serial.empty() ? "" : " serial " + id.serial);
}

Error UsbError(int rc, const std::string& what) {
  const std::string msg = what + ": " + libusb_error_name(rc);
  switch (rc) {
    case LIBUSB_ERROR_TIMEOUT:
      return Error{ErrorCode::kTimeout, msg};
    case LIBUSB_ERROR_NO_DEVICE:
    case LIBUSB_ERROR_NOT_FOUND:
      return Error{ErrorCode::kNotConnected, msg};
    default:
      return Error{ErrorCode::kIo, msg};
  }
}

}  // namespace

Result<std::unique_ptr<LibUsbTmcTransport>> LibUsbTmcTransport::Open(UsbDeviceId id) {
  std::unique_ptr<LibUsbTmcTransport> t(new LibUsbTmcTransport());
  t->id_ = std::move(id);
  const int rc = libusb_init(&t->ctx_);
  if (rc != 0) {
    t->ctx_ = nullptr;
    return Error{ErrorCode::kNotConnected, "source monitor " + IdText(t->id_) +
                                               ": no USB access here (" + libusb_error_name(rc) +
                                               ")"};
  }
  if (Status s = t->Find(); !s.ok()) return s.error();
  return t;
}

LibUsbTmcTransport::~LibUsbTmcTransport() {
  Close();
  if (ctx_ != nullptr) libusb_exit(ctx_);
}

void LibUsbTmcTransport::Close() {
  if (handle_ != nullptr) {
    if (interface_ >= 0) libusb_release_interface(handle_, interface_);
    libusb_close(handle_);
  }
  handle_ = nullptr;
  interface_ = -1;
}

Status LibUsbTmcTransport::Find() {
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx_, &list);
  if (n < 0) return UsbError(static_cast<int>(n), "listing USB devices");
  Status result = Error{ErrorCode::kNotConnected, "no USBTMC device " + IdText(id_) +
                                                      " found; is it plugged in and powered?"};
  for (ssize_t k = 0; k < n && handle_ == nullptr; ++k) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[k], &d) != 0 || d.idVendor != id_.vendor_id ||
        d.idProduct != id_.product_id)
      continue;
    libusb_device_handle* h = nullptr;
    const int rc = libusb_open(list[k], &h);
    if (rc == LIBUSB_ERROR_ACCESS) {
      result = Error{ErrorCode::kIo, "USBTMC device " + IdText(id_) +
                                         ": permission denied; add a udev rule giving the "
                                         "operators' group access (SUBSYSTEM==\"usb\", "
                                         "ATTRS{idVendor}==...)"};
      continue;
    }
    if (rc != 0) {
      result = UsbError(rc, "opening " + IdText(id_));
      continue;
    }
    if (!id_.serial.empty()) {
      unsigned char serial[128] = {};
      if (d.iSerialNumber == 0 ||
          libusb_get_string_descriptor_ascii(h, d.iSerialNumber, serial, sizeof serial) < 0 ||
          id_.serial != reinterpret_cast<char*>(serial)) {
        libusb_close(h);
        continue;
      }
    }
    // The USBTMC interface and its bulk endpoints.
    libusb_config_descriptor* cfg = nullptr;
    if (libusb_get_active_config_descriptor(list[k], &cfg) != 0) {
      libusb_close(h);
      continue;
    }
    for (int i = 0; i < cfg->bNumInterfaces && interface_ < 0; ++i) {
      const libusb_interface_descriptor& alt = cfg->interface[i].altsetting[0];
      if (alt.bInterfaceClass != 0xFE || alt.bInterfaceSubClass != 0x03) continue;
      for (int e = 0; e < alt.bNumEndpoints; ++e) {
        const libusb_endpoint_descriptor& ep = alt.endpoint[e];
        if ((ep.bmAttributes & 0x03) != LIBUSB_TRANSFER_TYPE_BULK) continue;
        (ep.bEndpointAddress & LIBUSB_ENDPOINT_IN ? ep_in_ : ep_out_) = ep.bEndpointAddress;
      }
      interface_ = alt.bInterfaceNumber;
    }
    libusb_free_config_descriptor(cfg);
    if (interface_ < 0 || ep_in_ == 0 || ep_out_ == 0) {
      libusb_close(h);
      interface_ = -1;
      result = Error{ErrorCode::kProtocol, IdText(id_) + " has no USBTMC interface"};
      continue;
    }
    // The kernel's usbtmc driver may hold the interface: detach it (re-attached on release).
    libusb_set_auto_detach_kernel_driver(h, 1);
    const int claim = libusb_claim_interface(h, interface_);
    if (claim != 0) {
      libusb_close(h);
      interface_ = -1;
      result = UsbError(claim, "claiming the USBTMC interface of " + IdText(id_) +
                                   " (is another program using it?)");
      continue;
    }
    handle_ = h;
    result = OkStatus();
  }
  libusb_free_device_list(list, 1);
  return result;
}

Status LibUsbTmcTransport::BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) {
  if (handle_ == nullptr) return Error{ErrorCode::kNotConnected, IdText(id_) + " is closed"};
  int done = 0;
  const int rc = libusb_bulk_transfer(handle_, ep_out_, const_cast<std::uint8_t*>(data),
                                      static_cast<int>(n), &done, timeout_ms);
  if (rc == LIBUSB_ERROR_PIPE) libusb_clear_halt(handle_, ep_out_);
  if (rc != 0) return UsbError(rc, "USBTMC bulk-out to " + IdText(id_));
  if (done != static_cast<int>(n)) return Error{ErrorCode::kIo, "USBTMC bulk-out: short transfer"};
  return OkStatus();
}

Result<std::size_t> LibUsbTmcTransport::BulkIn(std::uint8_t* data, std::size_t capacity,
                                               int timeout_ms) {
  if (handle_ == nullptr) return Error{ErrorCode::kNotConnected, IdText(id_) + " is closed"};
  int done = 0;
  const int rc =
      libusb_bulk_transfer(handle_, ep_in_, data, static_cast<int>(capacity), &done, timeout_ms);
  if (rc == LIBUSB_ERROR_PIPE) libusb_clear_halt(handle_, ep_in_);
  if (rc != 0) return UsbError(rc, "USBTMC bulk-in from " + IdText(id_));
  return static_cast<std::size_t>(done);
}

Result<std::vector<std::uint8_t>> LibUsbTmcTransport::ClassRequest(std::uint8_t request,
                                                                   std::uint16_t value,
                                                                   std::uint16_t length,
                                                                   int timeout_ms) {
  if (handle_ == nullptr) return Error{ErrorCode::kNotConnected, IdText(id_) + " is closed"};
  // The abort requests go to an endpoint (USBTMC 1.0 table 15), the others to the interface.
  const bool to_endpoint = request >= usbtmc_request::kInitiateAbortBulkOut &&
                           request <= usbtmc_request::kCheckAbortBulkInStatus;
  const auto type = static_cast<std::uint8_t>(
      static_cast<unsigned>(LIBUSB_ENDPOINT_IN) | static_cast<unsigned>(LIBUSB_REQUEST_TYPE_CLASS) |
      static_cast<unsigned>(to_endpoint ? LIBUSB_RECIPIENT_ENDPOINT : LIBUSB_RECIPIENT_INTERFACE));
  const bool bulk_in = request == usbtmc_request::kInitiateAbortBulkIn ||
                       request == usbtmc_request::kCheckAbortBulkInStatus;
  const std::uint16_t index =
      to_endpoint ? (bulk_in ? ep_in_ : ep_out_) : static_cast<std::uint16_t>(interface_);
  std::vector<std::uint8_t> buf(length);
  const int rc = libusb_control_transfer(handle_, type, request, value, index, buf.data(), length,
                                         static_cast<unsigned>(timeout_ms));
  if (rc < 0) return UsbError(rc, "USBTMC class request " + std::to_string(request));
  buf.resize(static_cast<std::size_t>(rc));
  return buf;
}

Status LibUsbTmcTransport::ClearHalt(devices::UsbTmcEndpoint endpoint) {
  if (handle_ == nullptr) return Error{ErrorCode::kNotConnected, IdText(id_) + " is closed"};
  const bool out = endpoint == devices::UsbTmcEndpoint::kBulkOut;
  const int rc = libusb_clear_halt(handle_, out ? ep_out_ : ep_in_);
  if (rc != 0) return UsbError(rc, "USBTMC clear halt of " + IdText(id_));
  return OkStatus();
}

Status LibUsbTmcTransport::Reopen() {
  Close();
  return Find();
}

}  // namespace gonio::backends
