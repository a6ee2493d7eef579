// Completeness of the register maps: every register address printed in a
// manual's register tables is covered by a register of its spec. The scan
// reads the manuals themselves (shared/manuals beside the checkout); each
// manual prints its tables differently, so each has its own small scan rule
// below, written from the manual's typography (not from the spec).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <regex>
#include <set>

#include "loader.h"
#include "manuals_dir.h"

using namespace mbc;
namespace fs = std::filesystem;

namespace {

struct Printed {
  uint16_t address;
  int line;
};

using Scan = std::function<void(const std::string& line, int n, std::vector<Printed>& out)>;

void add_range(std::vector<Printed>& out, unsigned a, unsigned b, int n) {
  for (unsigned x = a; x <= b && x <= 0xFFFF; ++x) out.push_back({uint16_t(x), n});
}

// 57HS-R §6.1: rows start "0x0020<TAB>" or "0x0090~0x009F<TAB>" (hex).
void scan_sihong(const std::string& line, int n, std::vector<Printed>& out) {
  static const std::regex row(R"(^0x([0-9A-F]{4})(?:\s*[~-]\s*0x([0-9A-F]{4}))?\t)");
  std::smatch m;
  if (!std::regex_search(line, m, row)) return;
  unsigned a = std::stoul(m[1], nullptr, 16);
  add_range(out, a, m[2].matched ? std::stoul(m[2], nullptr, 16) : a, n);
}

// HSC60 §四 register table: "<decimal><TAB><name><TAB><R|R/W|R/W/S>" (bit
// tables have a number in the third column, so they do not match).
void scan_hsc60(const std::string& line, int n, std::vector<Printed>& out) {
  static const std::regex row(R"(^(\d{1,3})\t[^\t]+\t(R|R/W|R/W/S)(\t|$))");
  std::smatch m;
  if (std::regex_search(line, m, row)) add_range(out, std::stoul(m[1]), std::stoul(m[1]), n);
}

// 7TRSM5740Q §6.2 tables 12-15 and the arrival tables: "| FC | 3004-3005 | ..." (decimal; ranges
// printed with "-" or "–").
void scan_hanstar(const std::string& line, int n, std::vector<Printed>& out) {
  static const std::regex row(R"(^\|\s*(03|06|16)\s*\|\s*(\d{4})(?:\s*(?:-|–)\s*(\d{4}))?\s*\|)");
  std::smatch m;
  if (!std::regex_search(line, m, row)) return;
  unsigned a = std::stoul(m[2]);
  add_range(out, a, m[3].matched ? std::stoul(m[3]) : a, n);
}

// Rieding appendix 1: "PN-01<TAB>0<TAB>...<TAB>PN-60<TAB>3B<TAB>..." (hex
// addresses, two parameters a row); command area "+02H" from 0800H and status
// area "+00H" from 0810H (§ (2) and (3) of the address list).
struct RiedingScan {
  unsigned base = 0;
  bool in_area = false;
  void operator()(const std::string& line, int n, std::vector<Printed>& out) {
    static const std::regex param(R"(PN-\d+\t([0-9A-F]{1,3})\t)");
    for (std::sregex_iterator it(line.begin(), line.end(), param), end; it != end; ++it) {
      unsigned a = std::stoul((*it)[1], nullptr, 16);
      add_range(out, a, a, n);
    }
    if (line.find("命令区的地址") != std::string::npos) base = 0x0800, in_area = true;
    else if (line.find("状态区的地址") != std::string::npos) base = 0x0810, in_area = true;
    else if (line.find("实例") != std::string::npos) in_area = false;
    static const std::regex offset(R"(^\+([0-9A-F]{2})H)");
    std::smatch m;
    if (in_area && std::regex_search(line, m, offset)) {
      unsigned a = base + std::stoul(m[1], nullptr, 16);
      add_range(out, a, a, n);
    }
  }
};

std::map<std::string, Scan> scans() {
  return {{"sihong-57hs-r", scan_sihong},
          {"hsc60", scan_hsc60},
          {"hanstar-7trsm5740q", scan_hanstar},
          {"rieding-dhe", RiedingScan{}}};
}

}  // namespace

TEST(Completeness, EveryPrintedRegisterIsInTheSpec) {
  auto dir = manuals_dir();
  if (!dir) GTEST_SKIP() << "shared/manuals not found (set MBCONFORM_MANUALS_DIR)";
  for (auto& [id, scan] : scans()) {
    spec::Spec s = spec::load_spec_by_id(id);
    fs::path manual = *dir / s.device.manual.file;
    ASSERT_TRUE(fs::exists(manual)) << manual;
    std::ifstream in(manual);
    std::vector<Printed> printed;
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) scan(line, n, printed);
    // Every manual prints a register map of some size: an empty scan means the rule broke.
    EXPECT_GE(printed.size(), 20u) << id << ": the scan of " << manual.filename() << " found almost no registers";
    std::set<uint16_t> seen;
    for (const auto& p : printed) {
      seen.insert(p.address);
      EXPECT_NE(s.register_covering(p.address), nullptr)
          << id << ": register " << p.address << " (0x" << std::hex << p.address << std::dec << ") printed at "
          << manual.filename().string() << ":" << p.line << " is not covered by any register of "
          << s.path;
    }
    std::cout << id << ": " << seen.size() << " printed register addresses, all in the spec\n";
  }
}
