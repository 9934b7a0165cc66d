// common/text.h: where the first byte that is not UTF-8 lies (RFC 3629's well-formed sequences),
// and a file refused with path:line:column.
#include "common/text.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace gonio {
namespace {

TEST(Utf8, WellFormedTextPasses) {
  EXPECT_FALSE(FirstInvalidUtf8(""));
  EXPECT_FALSE(FirstInvalidUtf8("plain ASCII\nsecond line\n"));
  EXPECT_FALSE(FirstInvalidUtf8("\xC2\xB0 \xCE\xB1 \xE2\x82\xAC \xF0\x9F\x94\xAC"));  // ° α € 🔬
  EXPECT_FALSE(FirstInvalidUtf8("\xED\x9F\xBF"));      // U+D7FF, just below the surrogates
  EXPECT_FALSE(FirstInvalidUtf8("\xF4\x8F\xBF\xBF"));  // U+10FFFF, the last code point
}

TEST(Utf8, IllFormedSequencesAreFoundWhereTheyStart) {
  struct Case {
    std::string text;
    int line, column;
    std::size_t offset;
  };
  const Case cases[] = {
      {"ab\xFF", 1, 3, 2},            // never a UTF-8 byte
      {"x\n\xC0\x80", 2, 1, 2},       // overlong NUL
      {"\xE0\x9F\xBF", 1, 1, 0},      // overlong three-byte form
      {"a\xED\xA0\x80", 1, 2, 1},     // a surrogate (U+D800)
      {"\xF4\x90\x80\x80", 1, 1, 0},  // above U+10FFFF
      {"\xF5\x80\x80\x80", 1, 1, 0},  // a lead byte that cannot occur
      {"ok\n\xCE\xB1\xCE", 2, 2, 5},  // a sequence cut short by the end (after one α)
      {"\x80", 1, 1, 0},              // a continuation byte with no lead
      {"a\xE2\x82z", 1, 2, 1},        // a lead byte followed by ASCII
      {"\n\n  \xC3\x28", 3, 3, 4},    // line and column of the lead byte
  };
  for (const Case& c : cases) {
    auto at = FirstInvalidUtf8(c.text);
    ASSERT_TRUE(at.has_value()) << c.offset;
    EXPECT_EQ(at->line, c.line) << c.offset;
    EXPECT_EQ(at->column, c.column) << c.offset;
    EXPECT_EQ(at->offset, c.offset);
  }
}

TEST(Utf8, AFileIsRefusedWithPathLineAndColumn) {
  const auto path = std::filesystem::temp_directory_path() /
                    ("gonio_text_" + std::to_string(::getpid()) + ".toml");
  {
    std::ofstream out(path, std::ios::binary);
    out << "sample = \"ground\"\nname = \"G\xFF\"\n";
  }
  auto text = ReadUtf8File(path.string());
  ASSERT_FALSE(text.ok());
  EXPECT_NE(text.error().message.find(path.string() + ":2:10: the file is not UTF-8 (byte 0xFF"),
            std::string::npos)
      << text.error().message;
  {
    std::ofstream out(path, std::ios::binary);
    out << "name = \"\xCE\xB1\"\n";
  }
  auto good = ReadUtf8File(path.string());
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, "name = \"\xCE\xB1\"\n");
  std::filesystem::remove(path);
  auto missing = ReadUtf8File(path.string());
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("cannot read"), std::string::npos);
}

}  // namespace
}  // namespace gonio
