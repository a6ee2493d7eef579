// A shipped device spec with some of its text changed, loaded as a user's
// spec file is: the tests that show a reference behaviour takes what the
// spec states from the spec (issue 38), not from constants of its own.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "engine/device.h"
#include "loader.h"

namespace mbc::ref {

// `dev` becomes the device of spec `id` with each `from` (found exactly once
// in its file) replaced by its `to`.
inline void load_changed_spec(Device& dev, const std::string& id,
                              const std::vector<std::pair<std::string, std::string>>& edits) {
  std::ifstream in(spec::spec_path(id));
  std::stringstream text;
  text << in.rdbuf();
  std::string yaml = text.str();
  ASSERT_FALSE(yaml.empty()) << spec::spec_path(id);
  for (const auto& [from, to] : edits) {
    const size_t at = yaml.find(from);
    ASSERT_NE(at, std::string::npos) << from;
    ASSERT_EQ(yaml.find(from, at + 1), std::string::npos) << from << " is in the spec more than once";
    yaml.replace(at, from.size(), to);
  }
  const auto* test = ::testing::UnitTest::GetInstance();
  const auto dir = std::filesystem::temp_directory_path() /
                   (id + "-changed-" + std::to_string(test->random_seed()) + "-" +
                    test->current_test_info()->test_suite_name() + "-" + test->current_test_info()->name());
  std::filesystem::create_directories(dir);
  const auto file = dir / (id + ".yaml");
  std::ofstream(file) << yaml;
  auto loaded = spec::load_spec_file(file.string());
  std::filesystem::remove_all(dir);
  ASSERT_TRUE(loaded.ok()) << (loaded.diagnostics.empty() ? "" : loaded.diagnostics.front().str());
  dev = Device(std::move(*loaded.spec), 1);
}

}  // namespace mbc::ref
