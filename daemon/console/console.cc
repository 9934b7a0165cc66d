#include "daemon/console/console.h"

namespace gonio::daemon {

const ConsoleFile* FindConsoleFile(std::string_view name) {
  if (name.empty()) name = "index.html";
  for (const ConsoleFile& f : EmbeddedConsoleFiles())
    if (f.name == name) return &f;
  return nullptr;
}

std::string_view ConsoleContentType(std::string_view name) {
  auto ends = [&](std::string_view ext) {
    return name.size() >= ext.size() && name.substr(name.size() - ext.size()) == ext;
  };
  if (ends(".html")) return "text/html; charset=utf-8";
  if (ends(".js")) return "text/javascript; charset=utf-8";
  if (ends(".css")) return "text/css; charset=utf-8";
  return "application/octet-stream";
}

}  // namespace gonio::daemon
