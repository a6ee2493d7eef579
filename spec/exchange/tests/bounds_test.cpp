// Readers bounded (issue 41 item 5): a template, a sheet or a spec of any
// depth or size is one clear line, never a crash; warnings are the first 20,
// then a count.
#include <fmt/core.h>

#include <string>

#include <gtest/gtest.h>

#include "exchange.h"
#include "loader.h"

namespace mbc::exchange {
namespace {

std::string nested(size_t depth, const std::string& open, const std::string& close, const std::string& inner = "1") {
  std::string s;
  s.reserve(depth * (open.size() + close.size()) + inner.size());
  for (size_t i = 0; i < depth; ++i) s += open;
  s += inner;
  for (size_t i = 0; i < depth; ++i) s += close;
  return s;
}

TEST(WbBounds, DeepJsonIsOneErrorNotACrash) {
  // 150,000 levels crashed the reader (SIGSEGV, a recursive copy).
  for (const std::string& text : {nested(150000, "[", "]"), "{\"device\": {\"id\": \"x\", \"channels\": " + nested(150000, "[", "]") + "}}",
                                  nested(150000, "{\"a\":", "}")}) {
    auto r = import_wb_template(text, "deep.json", "deep");
    ASSERT_EQ(r.errors.size(), 1u);
    EXPECT_EQ(r.errors[0], "deep.json: error: nesting deeper than 64 levels: not a device template");
    EXPECT_EQ(wb_template_id(text), "");
  }
  // 64 levels is still read (and then is not a template).
  auto r = import_wb_template(nested(63, "[", "]"), "ok.json", "ok");
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].find("no \"device\" object"), std::string::npos) << r.errors[0];
}

TEST(WbBounds, ATemplateOverTheCapIsOneError) {
  std::string big = "{\"device\": {\"id\": \"x\", \"channels\": [" + std::string(kMaxImportBytes, ' ') + "]}}";
  auto r = import_wb_template(big, "big.json", "big");
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].find("big.json: error: " + std::to_string(big.size()) + " bytes: a template is read up to 4 MiB"),
            std::string::npos)
      << r.errors[0];
}

TEST(WbBounds, WarningsAreTheFirst20ThenACount) {
  // One register, then 99 more channels on the same address: 99 warnings.
  std::string channels;
  for (int i = 0; i < 100; ++i) channels += fmt::format("{}{{\"name\": \"c{}\", \"address\": 7}}", i ? ", " : "", i);
  auto r = import_wb_template("{\"device\": {\"id\": \"x\", \"channels\": [" + channels + "]}}", "w.json", "w");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.warnings.size(), 21u);
  EXPECT_NE(r.warnings[0].find("a second channel on holding register 0x0007"), std::string::npos) << r.warnings[0];
  EXPECT_EQ(r.warnings[20], "w.json: 79 more warnings not shown (99 in all)");
}

TEST(CsvBounds, ASheetOverTheCapIsOneError) {
  std::string big = "address,name,access\n" + std::string(kMaxImportBytes, '#');
  auto r = import_csv(big, "big.csv", "big");
  ASSERT_EQ(r.errors.size(), 1u);
  EXPECT_NE(r.errors[0].find("big.csv:1: error: " + std::to_string(big.size()) + " bytes: a register sheet is read up to 4 MiB"),
            std::string::npos)
      << r.errors[0];
}

TEST(CsvBounds, WarningsAreTheFirst20ThenACount) {
  std::string header = "address,name,access";
  for (int i = 0; i < 30; ++i) header += fmt::format(",extra{}", i);
  auto r = import_csv(header + "\n0x10,Speed,rw\n", "w.csv", "w");
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.warnings.size(), 21u);
  EXPECT_NE(r.warnings[0].find("column 'extra0'"), std::string::npos) << r.warnings[0];
  EXPECT_EQ(r.warnings[20], "w.csv: 10 more warnings not shown (30 in all)");
}

// The spec loader (spec/loader/yaml_json.cpp): deep YAML is one `yaml` line.
void expect_too_deep(const std::string& text) {
  auto r = spec::load_spec_text(text, "deep.yaml");
  ASSERT_EQ(r.diagnostics.size(), 1u);
  EXPECT_EQ(r.diagnostics[0].rule, "yaml");
  EXPECT_NE(r.diagnostics[0].message.find("nesting deeper than"), std::string::npos) << r.diagnostics[0].message;
}

TEST(YamlBounds, DeepFlowAndBlockNesting) {
  expect_too_deep("a: " + nested(150000, "[", "]"));
  expect_too_deep("a: " + nested(150000, "{b: ", "}"));
  std::string block;
  for (int i = 0; i < 2000; ++i) block += std::string(size_t(i), ' ') + "k:\n";
  expect_too_deep(block);
}

TEST(YamlBounds, DeepNestingBehindMultiLineStrings) {
  // Each line closes a string the line before opened, then opens a flow
  // collection: a scanner that forgets a string at the end of a line reads
  // the brackets as quoted.
  std::string text = "a: [\"x\n";
  for (int i = 0; i < 150000; ++i) text += " \", [\"x\n";
  text += " \"" + std::string(150001, ']') + "\n";
  expect_too_deep(text);
  // A plain scalar holding a quote ("a \"b") is not a string.
  expect_too_deep("a: [a \"b, " + nested(150000, "[", "]") + "]\n");
}

}  // namespace
}  // namespace mbc::exchange
