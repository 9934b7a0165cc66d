// Text wrapped for a terminal: words filled into lines of at most `width` characters, each line
// after the first begun with `indent` (the first with `first_indent`). A word longer than a line
// stands on a line of its own, whole. Widths count bytes: the tools' texts are ASCII but for a
// few symbols, which this may count as two.
#pragma once

#include <cstddef>
#include <sstream>
#include <string>
#include <string_view>

namespace gonio {

inline std::string Wrap(std::string_view text, std::size_t width, std::string_view first_indent,
                        std::string_view indent) {
  std::string out, line(first_indent);
  bool line_has_word = false;
  std::istringstream words{std::string(text)};
  for (std::string word; words >> word;) {
    if (line_has_word && line.size() + 1 + word.size() > width) {
      out += line + "\n";
      line = std::string(indent);
      line_has_word = false;
    }
    if (line_has_word) line += ' ';
    line += word;
    line_has_word = true;
  }
  if (line_has_word) out += line + "\n";
  return out;
}

}  // namespace gonio
