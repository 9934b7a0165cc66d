// Text read from files that people write: bytes that must be UTF-8 before they go into JSON or a
// TOML parser, with the place of the first byte that is not (file:line:column, as every error
// about a file names it).
#pragma once

#include <cstdint>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>

#include "common/result.h"

namespace gonio {

struct TextPosition {
  int line = 1;    // 1-based
  int column = 1;  // 1-based, in bytes
  std::size_t offset = 0;
};

// The position of the first byte that does not begin or continue a well-formed UTF-8 sequence
// (RFC 3629: no overlong forms, no surrogates, nothing above U+10FFFF), or nullopt.
inline std::optional<TextPosition> FirstInvalidUtf8(std::string_view text) {
  TextPosition at;
  std::size_t i = 0;
  while (i < text.size()) {
    const auto b = static_cast<unsigned char>(text[i]);
    at.offset = i;
    int need = 0;
    unsigned lo = 0x80, hi = 0xBF;  // the range of the second byte
    if (b < 0x80) {
      need = 0;
    } else if (b >= 0xC2 && b <= 0xDF) {
      need = 1;
    } else if (b >= 0xE0 && b <= 0xEF) {
      need = 2;
      if (b == 0xE0) lo = 0xA0;  // overlong
      if (b == 0xED) hi = 0x9F;  // surrogates
    } else if (b >= 0xF0 && b <= 0xF4) {
      need = 3;
      if (b == 0xF0) lo = 0x90;  // overlong
      if (b == 0xF4) hi = 0x8F;  // above U+10FFFF
    } else {
      return at;
    }
    for (int k = 1; k <= need; ++k) {
      if (i + static_cast<std::size_t>(k) >= text.size()) return at;
      const auto c = static_cast<unsigned char>(text[i + static_cast<std::size_t>(k)]);
      if (c < (k == 1 ? lo : 0x80) || c > (k == 1 ? hi : 0xBF)) return at;
    }
    if (b == '\n') {
      ++at.line;
      at.column = 1;
    } else {
      ++at.column;  // one column per character
    }
    i += static_cast<std::size_t>(need) + 1;
  }
  return std::nullopt;
}

// A whole file as bytes, refused naming path:line:column when it is not UTF-8 and naming the
// path when it cannot be read.
inline Result<std::string> ReadUtf8File(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error{ErrorCode::kIo, path + ": cannot read the file"};
  std::ostringstream bytes;
  bytes << in.rdbuf();
  if (in.bad()) return Error{ErrorCode::kIo, path + ": reading the file failed"};
  std::string text = std::move(bytes).str();
  if (auto bad = FirstInvalidUtf8(text)) {
    char hex[8];
    std::snprintf(hex, sizeof hex, "0x%02X", static_cast<unsigned char>(text[bad->offset]));
    return InvalidArgument(path + ":" + std::to_string(bad->line) + ":" +
                           std::to_string(bad->column) + ": the file is not UTF-8 (byte " + hex +
                           " at offset " + std::to_string(bad->offset) + ")");
  }
  return text;
}

}  // namespace gonio
