// CRC-16 and frame parsing, with the manuals as the oracle: the frames below
// are copied from the manuals (section cited), not from our own output.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "loader.h"
#include "manuals_dir.h"
#include "modbus/crc16.h"
#include "modbus/hex.h"

using namespace mbc;
namespace fs = std::filesystem;

namespace {

Bytes hex(const char* s) {
  auto b = parse_hex(s);
  EXPECT_TRUE(b) << s;
  return b.value_or(Bytes{});
}

}  // namespace

// Frames whose printed CRC is right: each must verify.
TEST(Crc16, AcceptsTheManualsCorrectFrames) {
  for (const char* f : {
           "01 03 00 23 00 01 75 C0",                    // 57HS-R §6.2.1
           "01 03 08 00 05 00 64 00 64 00 3C F0 D1",     // 57HS-R §6.2.1
           "01 10 00 24 00 02 04 00 00 13 88 FD 12",     // 57HS-R §6.2.3
           "01 83 06 C1 32",                             // 57HS-R §6.2.4
           "01 06 00 30 00 01 48 05",                    // 57HS-R §7.6.3
           "01 03 02 0A 8C BF 41",                       // HSC60 §四 1.2.1
           "01 10 00 44 00 02 04 38 80 00 01 3B 24",     // HSC60 §四 1.2.3
           "01 10 00 44 00 02 01 DD",                    // HSC60 §四 1.2.3
           "01 03 03 EC 00 01 45 BB",                    // 7TRSM5740Q §6.3.1
           "01 10 07 D4 00 02 04 00 00 03 E8 D9 8E",     // 7TRSM5740Q §6.3.3 (frame line)
           "01 10 07 D4 00 02 00 84",                    // 7TRSM5740Q §6.3.3
           "01 06 08 04 FF D8 8B C1",                    // DHE §五
           "01 03 08 11 00 01 D6 6F",                    // DHE 附表二
       })
    EXPECT_TRUE(crc_ok(hex(f))) << f;
}

// Frames printed with a wrong CRC, and the CRC the standard's algorithm
// (MB over Serial Line v1.02 Appendix B) gives: both halves from outside the code.
TEST(Crc16, RejectsTheManualsWrongFrames) {
  struct Case {
    const char* printed;
    uint16_t correct;  // as sent: low byte first in the frame
  };
  for (const Case& c : {
           Case{"01 03 00 00 00 01 85 0A", 0x0A84},           // HSC60 §四 1.2.1
           Case{"01 03 00 20 00 01 85 C1", 0xC085},           // 57HS-R §6.2.4: the text names 85 C0
           Case{"01 82 02 61 C1", 0x61C1},                    // 57HS-R §6.2.4: bytes swapped
           Case{"01 06 08 00 01 51 6A 38", 0xC64B},           // DHE §五 速度模式运行 2
           Case{"01 06 08 00 01 61 6A 63", 0xD24B},           // DHE §五 速度模式运行 2
           Case{"01 10 07 D4 00 02 04 00 00 03 E8 D9 87", 0x8ED9},  // 7TRSM5740Q §6.3.3 byte table
       }) {
    Bytes b = hex(c.printed);
    EXPECT_FALSE(crc_ok(b)) << c.printed;
    EXPECT_EQ(crc16(std::span(b).first(b.size() - 2)), c.correct) << c.printed;
  }
}

// Completeness: every frame printed in a manual is an example in its spec.
// The scan reads the manuals themselves (shared/manuals beside the checkout).
namespace {

// Runs of at least five bytes printed as hex pairs (or pairs run together,
// "C9C1"), split on whitespace and punctuation.
std::vector<std::string> frames_printed_in(std::istream& in) {
  std::vector<std::string> out;
  std::string line;
  static const std::regex sep(R"([\s:;,|()']+|：|；|，|（|）)");
  static const std::regex pair(R"([0-9A-F]{2}|[0-9A-F]{4})");
  while (std::getline(in, line)) {
    std::string run;
    auto flush = [&] {
      if (run.size() >= 10) out.push_back(to_hex(*parse_hex(run)));
      run.clear();
    };
    for (std::sregex_token_iterator it(line.begin(), line.end(), sep, -1), end; it != end; ++it) {
      std::string tok = *it;
      if (std::regex_match(tok, pair)) run += tok;
      else flush();
    }
    flush();
  }
  return out;
}

std::vector<std::string> frames_printed_in(const fs::path& manual) {
  std::ifstream in(manual);
  return frames_printed_in(in);
}

}  // namespace

TEST(Completeness, EveryPrintedFrameIsAnExample) {
  auto dir = manuals_dir();
  if (!dir) GTEST_SKIP() << "shared/manuals not found (set MBCONFORM_MANUALS_DIR)";
  int manuals = 0;
  for (const auto& id : spec::spec_ids()) {
    spec::Spec s = spec::load_spec_by_id(id);
    fs::path manual = *dir / s.device.manual.file;
    if (!fs::exists(manual)) continue;  // modbus-standard has no manual file
    ++manuals;
    std::map<std::string, int> in_spec;
    for (const auto& e : s.examples) {
      ++in_spec[e.request];
      if (e.response && *e.response != e.request) ++in_spec[*e.response];
    }
    // A printed run of bytes that is not a frame (a partial table row) is
    // accounted for by the malformed_frame erratum that quotes it.
    for (const auto& e : s.errata) {
      if (e.kind != "malformed_frame") continue;
      std::istringstream quoted(e.printed);
      for (const auto& f : frames_printed_in(quoted)) ++in_spec[f];
    }
    std::map<std::string, int> printed;
    for (const auto& f : frames_printed_in(manual)) ++printed[f];
    EXPECT_FALSE(printed.empty()) << manual;
    for (const auto& [frame, n] : printed) {
      // A frame printed as request and echoed as response counts once per example.
      int have = in_spec[frame];
      for (const auto& e : s.examples)
        if (e.response && *e.response == e.request && e.request == frame) ++have;
      EXPECT_GE(have, n) << id << ": frame '" << frame << "' is printed " << n << " times in " << manual.filename()
                         << " but appears " << have << " times in the spec's examples";
    }
  }
  EXPECT_EQ(manuals, 4);
}
