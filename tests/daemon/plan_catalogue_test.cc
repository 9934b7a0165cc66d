// The instrument's plans (goniod --plans): only plain *.toml names directly in the directory,
// each checked against the instrument, its first comment as its description; names that could
// reach anything else are refused before the file system is touched.
#include "daemon/service/plan_catalogue.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

namespace gonio::daemon {
namespace {

class PlanCatalogueTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir = std::filesystem::temp_directory_path() / ("gonio_plans_" + std::to_string(::getpid()));
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir / "sub.toml");
    Write("plan_a.toml",
          "# Ground glass at normal incidence\nsample = \"G1\"\n[geometry]\nincidence_deg = [0]\n"
          "view_about = \"refracted\"\nview_from_deg = -10\nview_to_deg = 10\nview_step_deg = 5\n"
          "[rectangle]\nx = 253\ny = 246\nwidth = 6\nheight = 19\n");
    Write("plan_b.toml", "sample = \"nothing-like-it\"\n");
    Write("notes.txt", "not a plan");
    Write(".hidden.toml", "sample = \"G1\"\n");
    Write("sub.toml/inner.toml", "sample = \"G1\"\n");
    context.specimens = {{"G1", "glass", 6, 1.51, std::nullopt}};
  }
  void TearDown() override { std::filesystem::remove_all(dir); }
  void Write(const std::string& name, const std::string& text) {
    std::ofstream(dir / name, std::ios::binary) << text;
  }

  std::filesystem::path dir;
  acquisition::PlanContext context;
};

TEST_F(PlanCatalogueTest, ListsThePlainTomlFilesEachCheckedAgainstTheInstrument) {
  auto c = PlanCatalogue::Open(dir.string());
  ASSERT_TRUE(c.ok()) << c.error().message;
  auto list = c->List(context);
  ASSERT_TRUE(list.ok()) << list.error().message;
  ASSERT_EQ(list->size(), 2u);  // not notes.txt, .hidden.toml, the directory or what is inside it
  EXPECT_EQ((*list)[0].name, "plan_a.toml");
  EXPECT_TRUE((*list)[0].valid) << (*list)[0].error;
  EXPECT_EQ((*list)[0].description, "Ground glass at normal incidence");
  EXPECT_EQ((*list)[1].name, "plan_b.toml");
  EXPECT_FALSE((*list)[1].valid);
  EXPECT_NE((*list)[1].error.find("plan_b.toml:1"), std::string::npos) << (*list)[1].error;
  EXPECT_NE((*list)[1].error.find("nothing-like-it"), std::string::npos) << (*list)[1].error;
  auto text = c->Read("plan_a.toml");
  ASSERT_TRUE(text.ok());
  EXPECT_EQ(text->rfind("# Ground glass", 0), 0u);
}

TEST_F(PlanCatalogueTest, NamesThatCouldReachAnythingElseAreRefused) {
  auto c = PlanCatalogue::Open(dir.string());
  ASSERT_TRUE(c.ok());
  for (const char* bad : {"../plan_a.toml", "sub.toml/inner.toml", ".hidden.toml", "notes.txt",
                          "/etc/passwd", "", ".toml", "plan a.toml"}) {
    auto r = c->Read(bad);
    ASSERT_FALSE(r.ok()) << bad;
    EXPECT_EQ(r.error().code, ErrorCode::kInvalidArgument) << bad;
  }
  auto missing = c->Read("plan_c.toml");
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  auto dir_named = c->Read("sub.toml");
  ASSERT_FALSE(dir_named.ok());
  EXPECT_EQ(dir_named.error().code, ErrorCode::kNotFound);
  Write("huge.toml", std::string(PlanCatalogue::kMaxBytes + 1, '#'));
  auto huge = c->Read("huge.toml");
  ASSERT_FALSE(huge.ok());
  EXPECT_NE(huge.error().message.find("larger than"), std::string::npos);
  EXPECT_FALSE(PlanCatalogue::Open((dir / "plan_a.toml").string()).ok());
  EXPECT_FALSE(PlanCatalogue::Open((dir / "none").string()).ok());
}

}  // namespace
}  // namespace gonio::daemon
