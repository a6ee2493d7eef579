#include "map/map.h"

#include <fmt/core.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <charconv>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include "modbus/hex.h"
#include "modbus/judge.h"
#include "modbus/rtu.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"
#include "yaml_json.h"

namespace mbc::conf::map {
namespace {

using spec::Table;

struct TableInfo {
  Table table;
  const char* name;    // as --map and map files spell it
  uint8_t read_fc;     // MBAP v1.1b3 §6.1-6.4
  uint16_t max_read;   // the standard's quantity limit of that read
};
// Holding registers first: most servers map them, and a budget that runs out
// should have spent itself on them.
constexpr TableInfo kTables[] = {
    {Table::holding, "holding", 3, uint16_t(standard_max_quantity(3))},
    {Table::coil, "coils", 1, uint16_t(standard_max_quantity(1))},
    {Table::input, "input", 4, uint16_t(standard_max_quantity(4))},
    {Table::discrete_input, "discrete", 2, uint16_t(standard_max_quantity(2))},
};

const TableInfo& info_of(Table t) {
  for (const auto& i : kTables)
    if (i.table == t) return i;
  return kTables[0];
}

std::optional<Table> table_named(const std::string& n) {
  if (n == "holding" || n == "holding_registers" || n == "hr") return Table::holding;
  if (n == "coils" || n == "coil") return Table::coil;
  if (n == "input" || n == "input_registers" || n == "ir") return Table::input;
  if (n == "discrete" || n == "discrete_inputs" || n == "discrete_input" || n == "di") return Table::discrete_input;
  return std::nullopt;
}

void sort_blocks(Map& m) {
  std::sort(m.blocks.begin(), m.blocks.end(), [](const Block& a, const Block& b) {
    return std::pair(int(a.table), a.first) < std::pair(int(b.table), b.first);
  });
}

// ---- probe ----

// The probe (map.h): a table's state per address, filled by reads.
enum class Seen : uint8_t { unknown, mapped, unmapped };

// Where vendors put registers beyond the first few hundred: at round
// decimal and hex bases, a few words in. The likeliest first: 1000s up to
// 10000 and 0x1000s; then 100s up to 10000 and 0x100s up to 0x2000; then
// the 1000s above 10000; then 10s and 0x10s. Each tier is tried in every
// table before the next, so a budget or time bound that runs out loses the
// least likely places first.
struct SeedTier {
  std::vector<uint32_t> bases;
  uint32_t offsets;  // base + 0 .. base + offsets - 1
};

std::vector<SeedTier> seed_tiers() {
  auto multiples = [](std::vector<uint32_t>& out, uint32_t step, uint32_t from, uint32_t upto) {
    for (uint32_t b = from; b <= upto && b <= 0xFFFF; b += step) out.push_back(b);
  };
  std::vector<SeedTier> tiers(4);
  multiples(tiers[0].bases, 1000, 1000, 10000);
  multiples(tiers[0].bases, 0x1000, 0x1000, 0xFFFF);
  tiers[0].offsets = 4;
  multiples(tiers[1].bases, 100, 100, 10000);
  multiples(tiers[1].bases, 0x100, 0x100, 0x2000);
  tiers[1].offsets = 4;
  multiples(tiers[2].bases, 1000, 11000, 0xFFFF);
  tiers[2].offsets = 4;
  multiples(tiers[3].bases, 10, 10, 1000);
  multiples(tiers[3].bases, 0x10, 0x10, 0x400);
  tiers[3].offsets = 2;
  std::vector<uint32_t> earlier;
  for (auto& t : tiers) {
    std::sort(t.bases.begin(), t.bases.end());
    t.bases.erase(std::unique(t.bases.begin(), t.bases.end()), t.bases.end());
    // A base an earlier tier tried is not tried again.
    std::erase_if(t.bases, [&](uint32_t b) { return std::binary_search(earlier.begin(), earlier.end(), b); });
    earlier.insert(earlier.end(), t.bases.begin(), t.bases.end());
    std::sort(earlier.begin(), earlier.end());
  }
  return tiers;
}

class Prober {
 public:
  Prober(Link& t, const ProbeLimits& limits) : t_(t), limits_(limits) {}

  Map run() {
    m_.source = "probe of " + t_.info().uri;
    t0_ = std::chrono::steady_clock::now();
    // Replies are expected to reads; an unmapped address may be silent, so
    // a read waits the adaptive window, and a read whose reply came late is
    // read again.
    explore();
    m_.requests = used_;
    m_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count();
    for (const auto& ti : kTables) {
      const auto& s = seen_[int(ti.table)];
      for (uint32_t a = 0; a <= 0xFFFF; ++a) {
        if (s[a] != Seen::mapped) continue;
        uint32_t b = a;
        while (b < 0xFFFF && s[b + 1] == Seen::mapped) ++b;
        m_.blocks.push_back({ti.table, uint16_t(a), uint16_t(b), std::nullopt});
        a = b;
      }
    }
    sort_blocks(m_);
    if (!ok_latency_.empty() || !exception_latency_.empty())
      m_.notes.push_back(fmt::format("replies took {} (median of {}), exceptions {} (median of {})", median_ms(ok_latency_),
                                     ok_latency_.size(), median_ms(exception_latency_), exception_latency_.size()));
    return std::move(m_);
  }

 private:
  enum class Answer { mapped, unmapped, unsupported, out };  // out: budget or time ran out

  struct Stop {};  // the budget or the time ran out

  static std::string median_ms(std::vector<double> v) {
    if (v.empty()) return "-";
    std::nth_element(v.begin(), v.begin() + long(v.size() / 2), v.end());
    return fmt::format("{:.1f} ms", v[v.size() / 2]);
  }

  bool out() {
    if (used_ >= limits_.budget) return true;
    if (limits_.time && std::chrono::steady_clock::now() - t0_ >= *limits_.time) return true;
    return false;
  }

  void stop(const TableInfo& ti, uint32_t at) {
    m_.partial = true;
    bool by_time = used_ < limits_.budget;
    m_.partial_at = fmt::format("{} 0x{:04X}", ti.name, at);
    m_.partial_by = by_time ? "time" : "budget";
    throw Stop{};
  }

  // A read of `quantity` items from `address`; throws Stop when out of budget or time.
  Answer read(const TableInfo& ti, uint32_t address, uint32_t quantity, std::string* what = nullptr) {
    Bytes req = read_request(ti.read_fc, uint16_t(address), uint16_t(quantity));
    for (int attempt = 0;; ++attempt) {
      if (out()) stop(ti, address);
      ++used_;
      if (limits_.on_request) limits_.on_request(used_, limits_.budget);
      uint64_t late = t_.late_replies();
      Reply r = reply_or_throw(t_.transact(t_.info().unit, req, Target::Wait::window), t_.info());
      if (t_.late_replies() != late && attempt < 2) continue;  // the window widened: ask again
      double ms = std::chrono::duration<double, std::milli>(r.latency).count();
      std::string answer;
      if (r.pdu && !r.pdu->empty() && !((*r.pdu)[0] & 0x80)) {
        Judged j = judge_reply(req, *r.pdu);
        if (j.ok()) {
          ok_latency_.push_back(ms);
          if (quantity == 1) seen_[int(ti.table)][address] = Seen::mapped;
          return Answer::mapped;
        }
        answer = "a malformed reply (" + (j.problems.empty() ? std::string("unreadable") : j.problems.front()) + ")";
      } else if (r.pdu && r.pdu->size() >= 2) {
        exception_latency_.push_back(ms);
        answer = fmt::format("exception {:02X}", (*r.pdu)[1]);
        if ((*r.pdu)[1] == 1) {
          note(ti.table, answer + " (function not supported)");
          return Answer::unsupported;
        }
      } else {
        answer = r.silent() ? "silence" : "an unusable reply: " + r.framing_error;
      }
      if (quantity == 1) {
        note(ti.table, answer);
        seen_[int(ti.table)][address] = Seen::unmapped;
      }
      if (what) *what = answer;
      return Answer::unmapped;
    }
  }

  Seen& at(const TableInfo& ti, uint32_t a) { return seen_[int(ti.table)][a]; }

  // A single read of `a` unless it is known; true when mapped.
  bool single(const TableInfo& ti, uint32_t a) {
    if (at(ti, a) != Seen::unknown) return at(ti, a) == Seen::mapped;
    return read(ti, a, 1) == Answer::mapped;
  }

  // From `a`, a run of mapped addresses: reads of the standard's maximum
  // quantity, the end found by bisection. Returns the last mapped address
  // (a - 1 when `a` itself is not). A multi-item read says nothing of each
  // item, so the end it gives is checked with a single read: a server that
  // answers a read of bits in full though its last bits are past its table
  // (MBAP v1.1b3 §6.1 wants exception 02) deviates, and is reported.
  uint32_t grow(const TableInfo& ti, uint32_t a) {
    uint32_t last = a - 1;  // a >= 1 here: address 0 is always read singly first
    // Reads of 4, 8, 16, ... items up to the limit: a short run costs a few
    // reads, a long one a read per limit.
    for (uint32_t step = 4;; step = std::min<uint32_t>(step * 2, ti.max_read)) {
      if (last == 0xFFFF) break;
      uint32_t n = std::min<uint32_t>(step, 0xFFFF - last);
      if (read(ti, last + 1, n) == Answer::mapped) {
        last += n;
        continue;
      }
      uint32_t lo = 0, hi = n;  // reads of lo items from last + 1 answer, of hi do not
      while (hi - lo > 1) {
        uint32_t mid = lo + (hi - lo) / 2;
        (read(ti, last + 1, mid) == Answer::mapped ? lo : hi) = mid;
      }
      // The read that failed may have failed for its quantity (a device's
      // own limit below the standard's), not for last + 1: that address is
      // left to a single read.
      last += lo;
      break;
    }
    if (last + 1 == a) return last;
    // Check the end singly, backing off over what a single read refuses.
    uint32_t claimed = last;
    std::string refused;
    while (last >= a && at(ti, last) != Seen::mapped) {
      at(ti, last) = Seen::unknown;
      if (read(ti, last, 1, &refused) == Answer::mapped) break;
      at(ti, last) = Seen::unmapped;
      --last;
    }
    for (uint32_t x = a; x <= last; ++x) at(ti, x) = Seen::mapped;
    if (last != claimed)
      m_.deviations.push_back(fmt::format(
          "{}: a read through 0x{:04X} answered in full, but a read of 0x{:04X} alone got {}: the server answers for "
          "addresses past its table's end (MBAP v1.1b3 §6.{}: exception 02 when address + quantity is past the table); "
          "the map ends at 0x{:04X}",
          ti.name, claimed, claimed, refused, int(ti.read_fc), last));
    return last;
  }

  // Single reads from `from` on: a run of `run_to_grow` mapped addresses is
  // grown with full reads; stops after `gap` unmapped addresses in a row
  // once past `min_end`.
  void scan(const TableInfo& ti, uint32_t from, uint32_t min_end, uint32_t gap) {
    uint32_t misses = 0, run = 0;
    for (uint32_t a = from; a <= 0xFFFF && (a < min_end || misses < gap); ++a) {
      if (run >= 3 && at(ti, a) == Seen::unknown) {
        uint32_t last = grow(ti, a);
        run = 0;
        if (last + 1 != a) {
          a = last;  // the loop steps past the unmapped address after the run
          misses = 0;
          continue;
        }
      }
      if (single(ti, a)) {
        ++run;
        misses = 0;
      } else {
        run = 0;
        ++misses;
      }
    }
  }

  // Around an address found by a seed: back to the start of its cluster,
  // then on to its end.
  void cluster(const TableInfo& ti, uint32_t a) {
    uint32_t misses = 0;
    for (uint32_t b = a; b-- > 0 && misses < kClusterGap;) misses = single(ti, b) ? 0 : misses + 1;
    scan(ti, a + 1, a + 1, kClusterGap);
  }

  void explore() {
    std::vector<const TableInfo*> tables;
    try {
      // Which tables answer at all (exception 01: the function is not supported).
      for (const auto& ti : kTables)
        if (read(ti, 0, 1) != Answer::unsupported) tables.push_back(&ti);
      // The first few hundred addresses, one by one: where most drives keep their maps.
      for (const auto* ti : tables) scan(*ti, 1, kDenseSpan, kDenseGap);
      for (const auto& tier : seed_tiers())
        for (const auto* ti : tables)
          for (uint32_t base : tier.bases)
            for (uint32_t o = 0; o < tier.offsets && base + o <= 0xFFFF; ++o) {
              uint32_t a = base + o;
              if (at(*ti, a) != Seen::unknown) continue;
              if (single(*ti, a)) {
                cluster(*ti, a);
                break;
              }
            }
    } catch (const Stop&) {
    }
  }

  static constexpr uint32_t kDenseGap = 64, kClusterGap = 16;

  Link& t_;
  ProbeLimits limits_;
  int used_ = 0;
  std::chrono::steady_clock::time_point t0_;
  std::array<std::vector<Seen>, 4> seen_{std::vector<Seen>(0x10000), std::vector<Seen>(0x10000), std::vector<Seen>(0x10000),
                                         std::vector<Seen>(0x10000)};
  std::vector<double> ok_latency_, exception_latency_;
  Map m_;

  void note(Table t, const std::string& answer) {
    for (auto& u : m_.unmapped)
      if (u.table == t && u.answer == answer) {
        ++u.seen;
        return;
      }
    m_.unmapped.push_back({t, answer, 1});
  }
};

// ---- text ----

uint32_t number(const std::string& s, const std::string& where) {
  uint32_t v = 0;
  int base = 10;
  std::string d = s;
  if (d.size() > 2 && d[0] == '0' && (d[1] == 'x' || d[1] == 'X')) {
    base = 16;
    d = d.substr(2);
  }
  auto [end, ec] = std::from_chars(d.data(), d.data() + d.size(), v, base);
  if (d.empty() || ec != std::errc{} || end != d.data() + d.size() || v > 0xFFFF)
    throw std::invalid_argument(fmt::format("{}: '{}' is not an address 0..65535", where, s));
  return v;
}

std::optional<spec::Access> access_named(const std::string& a, const std::string& where) {
  if (a.empty()) return std::nullopt;
  if (a == "rw") return spec::Access::rw;
  if (a == "ro") return spec::Access::ro;
  throw std::invalid_argument(fmt::format("{}: access '{}': expected rw or ro", where, a));
}

void add_block(Map& m, Table t, uint32_t first, uint32_t last, std::optional<spec::Access> access, const std::string& where) {
  if (last < first) throw std::invalid_argument(fmt::format("{}: range ends before it starts", where));
  if ((t == Table::input || t == Table::discrete_input) && access == spec::Access::rw)
    throw std::invalid_argument(fmt::format("{}: {} cannot be written by any function code (MBAP v1.1b3 §4.3)", where, info_of(t).name));
  for (const auto& b : m.blocks)
    if (b.table == t && !(last < b.first || first > b.last))
      throw std::invalid_argument(fmt::format("{}: overlaps {} 0x{:04X}-0x{:04X}", where, info_of(t).name, b.first, b.last));
  m.blocks.push_back({t, uint16_t(first), uint16_t(last), access});
}

}  // namespace

bool Map::access_known() const {
  return std::all_of(blocks.begin(), blocks.end(), [](const Block& b) { return b.access.has_value(); });
}

bool Map::covers(Table t, uint16_t address) const {
  return std::any_of(blocks.begin(), blocks.end(), [&](const Block& b) { return b.table == t && b.first <= address && address <= b.last; });
}

std::string Map::describe() const {
  std::string s;
  for (const auto& b : blocks)
    s += fmt::format("{}{} 0x{:04X}-0x{:04X}{}", s.empty() ? "" : ", ", info_of(b.table).name, b.first, b.last,
                     b.access ? std::string(" ") + spec::to_string(*b.access) : "");
  return s.empty() ? "(nothing mapped)" : s;
}

int planned_requests(int budget) { return budget; }

std::vector<std::string> probe_notes(const Map& m) {
  std::vector<std::string> out;
  out.push_back(fmt::format("map probed in {} requests, {:.2f} s: {}", m.requests, m.seconds, m.describe()));
  for (const auto& u : m.unmapped)
    out.push_back(fmt::format("unmapped {} addresses answered: {} ({} probes)", table_name(u.table), u.answer, u.seen));
  if (m.partial)
    out.push_back(fmt::format("PARTIAL MAP: the probe's {} ran out at {}; nothing past it was probed (--map-{})", m.partial_by,
                              m.partial_at, m.partial_by));
  for (const auto& d : m.deviations) out.push_back("DEVIATION while probing: " + d);
  for (const auto& n : m.notes) out.push_back("probe: " + n);
  return out;
}

const char* table_name(Table t) { return info_of(t).name; }

Map probe(Link& target, const ProbeLimits& limits) { return Prober(target, limits).run(); }

Map probe(Link& target, int budget) { return probe(target, ProbeLimits{budget, std::nullopt, nullptr}); }

Map parse_inline(const std::string& text) {
  Map m;
  m.source = "inline";
  std::stringstream parts(text);
  std::string part;
  while (std::getline(parts, part, ',')) {
    if (part.empty()) continue;
    auto eq = part.find('=');
    std::string where = fmt::format("--map '{}': '{}'", text, part);
    if (eq == std::string::npos) throw std::invalid_argument(where + ": expected TABLE=FIRST-LAST");
    auto t = table_named(part.substr(0, eq));
    if (!t) throw std::invalid_argument(where + ": table is holding, coils, input or discrete");
    std::stringstream ranges(part.substr(eq + 1));
    std::string range;
    while (std::getline(ranges, range, '+')) {
      std::string access;
      if (auto c = range.find(':'); c != std::string::npos) {
        access = range.substr(c + 1);
        range = range.substr(0, c);
      }
      auto dash = range.find('-');
      uint32_t first = number(range.substr(0, dash), where);
      uint32_t last = dash == std::string::npos ? first : number(range.substr(dash + 1), where);
      add_block(m, *t, first, last, access_named(access, where), where);
    }
  }
  if (m.blocks.empty()) throw std::invalid_argument(fmt::format("--map '{}': no ranges", text));
  sort_blocks(m);
  return m;
}

Map load_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("{}:0:0: error: map: cannot read the file", path));
  std::stringstream ss;
  ss << in.rdbuf();
  spec::Diagnostics diags;
  auto doc = spec::yaml_to_json(ss.str(), path, diags);
  if (!doc) throw std::runtime_error(diags.empty() ? path + ":0:0: error: yaml: unreadable" : diags.front().str());
  auto fail = [&](const std::string& pointer, const std::string& what) {
    spec::SourceLoc at = doc->where(pointer);
    return std::runtime_error(fmt::format("{}:{}:{}: error: map: {}", path, at.line, at.col, what));
  };
  const auto& root = doc->root;
  if (!root.is_object() || root.value("mbconform_map", 0) != 1)
    throw fail("", "expected 'mbconform_map: 1' and the tables (holding, coils, input, discrete)");
  Map m;
  m.source = "file " + path;
  for (const auto& [key, ranges] : root.items()) {
    if (key == "mbconform_map") continue;
    auto t = table_named(key);
    std::string at = "/" + key;
    if (!t) throw fail(at, fmt::format("unknown table '{}' (holding, coils, input, discrete)", key));
    if (!ranges.is_array()) throw fail(at, "expected a list of {from, to, access}");
    for (size_t i = 0; i < ranges.size(); ++i) {
      const auto& r = ranges[i];
      std::string ra = fmt::format("{}/{}", at, i);
      // YAML integers arrive signed: an address is any integer >= 0.
      auto address = [](const nlohmann::json& v) { return v.is_number_integer() && v.get<int64_t>() >= 0; };
      if (!r.is_object() || !r.contains("from") || !address(r["from"]))
        throw fail(ra, "expected {from: N, to: N, access: rw|ro}");
      for (const auto& [k, v] : r.items())
        if (k != "from" && k != "to" && k != "access") throw fail(ra + "/" + k, fmt::format("unknown key '{}'", k));
      uint64_t first = r["from"].get<uint64_t>();
      if (r.contains("to") && !address(r["to"])) throw fail(ra + "/to", "expected an address 0..65535");
      uint64_t last = r.contains("to") ? r["to"].get<uint64_t>() : first;
      if (first > 0xFFFF || last > 0xFFFF) throw fail(ra, "addresses are 0..65535");
      try {
        add_block(m, *t, uint32_t(first), uint32_t(last), access_named(r.value("access", std::string()), key),
                  fmt::format("{} {}-{}", key, first, last));
      } catch (const std::invalid_argument& e) {
        throw fail(ra, e.what());
      }
    }
  }
  if (m.blocks.empty()) throw fail("", "no ranges");
  sort_blocks(m);
  return m;
}

Map parse_option(const std::string& text) {
  std::error_code ec;
  if (std::filesystem::is_regular_file(text, ec) || text.ends_with(".yaml") || text.ends_with(".yml")) return load_file(text);
  return parse_inline(text);
}

std::string skeleton_yaml(const Map& m, const std::string& id, uint8_t unit) {
  std::string y = fmt::format(
      "# Written by `mbconform spec discover` from a {} ({} read requests, FC 01/02/03/04;\n"
      "# nothing was written). Every fact below is OBSERVED: what the server answered, not\n"
      "# what a manual states. Make it a spec: name the device, state what its manual\n"
      "# states (line settings, writability, limits, exception policy) and cite the sections.\n"
      "{}"
      "mbconform_spec: 1\n"
      "device:\n"
      "  id: {}\n"
      "  vendor: unknown\n"
      "  title: \"observed by mbconform spec discover\"\n"
      "  models: [unknown]\n"
      "  manual: {{file: \"{}\", source: discover, address_notation: hex}}  # every fact observed\n"
      "serial:  # not observable over the probe; placeholders from MB-SL v1.02 2.2, 2.5.1, 3.2\n"
      "  slave_id: {{min: 1, max: 247, default: {}}}\n"
      "  broadcast: {{address: 0, writes: applied, reply: none}}\n"
      "  baud_rates: {{values: [19200], default: 19200}}\n"
      "  frame_formats: {{values: [8E1], default: 8E1}}\n"
      "profile:\n"
      "  function_codes:  # the reads that answered; writes were not probed\n",
      m.source, m.requests,
      [&] {
        std::string s = m.partial ? fmt::format("# PARTIAL: the probe's {} ran out at {}; nothing past it was probed.\n", m.partial_by, m.partial_at) : "";
        for (const auto& d : m.deviations) s += "# DEVIATION: " + d + "\n";
        return s;
      }(),
      id, "mbconform spec discover, " + m.source, unit ? unit : 1);
  bool any = false;
  for (const auto& ti : kTables) {
    bool present = std::any_of(m.blocks.begin(), m.blocks.end(), [&](const Block& b) { return b.table == ti.table; });
    if (!present) continue;
    any = true;
    y += fmt::format("    - {{code: {}, section: \"observed\", note: \"observed: reads of {} answered\"}}\n", int(ti.read_fc), ti.name);
  }
  if (!any) y += "    - {code: 3, section: \"observed\", note: \"placeholder: no read answered\"}\n";
  // The answer to an unmapped address, when every table that answered agreed on one exception.
  std::string unmapped = "unspecified";
  for (const auto& u : m.unmapped) {
    if (u.answer.rfind("exception 0", 0) != 0 || u.answer.find("not supported") != std::string::npos) continue;
    std::string e = fmt::format("{{exception: {}, section: \"observed\"}}", u.answer.substr(std::string("exception ").size()));
    if (unmapped == "unspecified" || unmapped == e) unmapped = e;
    else unmapped = "mixed";
  }
  if (unmapped == "mixed") unmapped = "unspecified";
  y += fmt::format(
      "  exception_policy:  # observed: {}\n"
      "    unsupported_function: unspecified\n"
      "    unmapped_address: {}\n"
      "    address_past_map: {}\n"
      "    quantity_over_limit: unspecified\n"
      "    value_out_of_range: unspecified\n"
      "    write_read_only: unspecified\n"
      "    read_write_only: unspecified\n"
      "    crc_error: unspecified\n"
      "    wrong_byte_count: unspecified\n"
      "registers:{}\n",
      m.unmapped.empty() ? std::string("nothing unmapped was met")
                         : [&] {
                             std::string s;
                             for (const auto& u : m.unmapped)
                               s += fmt::format("{}{} unmapped -> {} ({}x)", s.empty() ? "" : "; ", table_name(u.table), u.answer, u.seen);
                             return s;
                           }(),
      unmapped, unmapped, m.blocks.empty() ? " []" : "");
  for (const auto& b : m.blocks) {
    bool bits = b.table == Table::coil || b.table == Table::discrete_input;
    const char* table = b.table == Table::holding ? "holding" : b.table == Table::input ? "input" : b.table == Table::coil ? "coil" : "discrete_input";
    y += fmt::format("  - {{address: 0x{:04X}, count: {}, table: {}, name: {{en: \"{} 0x{:04X}-0x{:04X}\"}}, access: ro, type: {}, "
                     "section: \"observed\", basis: {{read: {{observed: \"reads answered\"}}, write: {{observed: \"not probed: probing never "
                     "writes\"}}}}, note: \"observed: reads answered; writability was not probed (probing never writes)\"}}\n",
                     b.first, b.last - b.first + 1, table, table_name(b.table), b.first, b.last, bits ? "bit" : "u16");
  }
  y += "examples: []\nerrata: []\n";
  return y;
}

OnMap terms(const Map&) { return OnMap{}; }

namespace {

// Every (table, address) an example reads, writes or states (request
// address and quantity of FC 01-06, 15, 16, 22, 23; given; after).
bool example_inside(const spec::Example& ex, const Map& m) {
  auto inside = [&](Table t, uint32_t a, uint32_t n) {
    for (uint32_t i = 0; i < n; ++i)
      if (a + i > 0xFFFF || !m.covers(t, uint16_t(a + i))) return false;
    return true;
  };
  for (const auto& v : ex.given)
    if (!inside(v.table, v.address, 1)) return false;
  for (const auto& v : ex.after)
    if (!inside(v.table, v.address, 1)) return false;
  auto parsed = parse_hex(ex.resolved_request.value_or(ex.request));
  if (!parsed || parsed->size() < 4) return false;
  const Bytes& adu = *parsed;
  Bytes pdu = rtu_unframe(adu).pdu;
  if (pdu.size() < 5) return false;
  auto be = [&](size_t at) { return uint32_t(pdu[at] << 8 | pdu[at + 1]); };
  // The most addresses one request can touch in a table: its read's limit.
  auto most = [](Table t) { return uint32_t(info_of(t).max_read); };
  uint8_t fc = pdu[0];
  if (adu[0] == 0) return false;  // broadcast: what it means depends on the transport
  // An answer of exception 02 or 04 comes from the spec's own device's map
  // and ranges (an unmapped or read-only address, an application range),
  // which the server's map does not carry.
  if (auto rsp = ex.resolved_response ? ex.resolved_response : ex.response)
    if (auto r = parse_hex(*rsp); r && r->size() >= 3 && ((*r)[1] & 0x80) && ((*r)[2] == 2 || (*r)[2] == 4)) return false;
  switch (fc) {
    case 1: case 2: case 3: case 4: {
      Table t = spec::table_for_function(fc);
      return inside(t, be(1), std::min<uint32_t>(be(3), most(t)));
    }
    case 5: return inside(Table::coil, be(1), 1);
    case 6: case 22: return inside(Table::holding, be(1), 1);
    case 15: return inside(Table::coil, be(1), std::min<uint32_t>(be(3), most(Table::coil)));
    case 16: return inside(Table::holding, be(1), std::min<uint32_t>(be(3), most(Table::holding)));
    case 23:
      return pdu.size() >= 9 && inside(Table::holding, be(1), std::min<uint32_t>(be(3), most(Table::holding))) &&
             inside(Table::holding, be(5), std::min<uint32_t>(be(7), most(Table::holding)));
    default: return false;  // FC 07, 08, 11, 12, 17, 20, 21, 24, 43: the device's own contents
  }
}

}  // namespace

namespace {
spec::FactBasis basis(spec::Basis kind, const std::string& why) {
  spec::FactBasis b;
  b.basis = kind;
  b.why = why;
  return b;
}
}  // namespace

spec::Spec apply(const spec::Spec& base, const Map& m) {
  spec::Spec s = base;
  s.registers.clear();
  // The facts are now the map's, not the base spec's manual's: a probe's
  // (observed), or a map's that leaves some access unstated. The frame
  // policy then lets no write out to a live target without --allow-writes,
  // wherever it goes (a probe does not see a write-only register).
  const bool probed = m.source.rfind("probe of ", 0) == 0;
  if (probed) s.device.manual.source = "probe";
  else if (!m.access_known()) s.device.manual.source = "map";
  for (const auto& b : m.blocks) {
    bool bits = b.table == Table::coil || b.table == Table::discrete_input;
    bool writable_table = b.table == Table::holding || b.table == Table::coil;
    for (uint32_t a = b.first; a <= b.last; ++a) {
      spec::Register r;
      r.address = uint16_t(a);
      r.table = b.table;
      r.type = bits ? spec::DataType::bit : spec::DataType::u16;
      r.access = b.access.value_or(writable_table ? spec::Access::rw : spec::Access::ro);
      r.key = fmt::format("{}[{}]", info_of(b.table).name, a);
      r.name.en = fmt::format("{} 0x{:04X} ({})", info_of(b.table).name, a, m.source);
      r.section = "MBAP 4.3";
      // A probed fact is observed, never stated (spec/README.md, "Where each
      // fact comes from"); a given map states what it says, and a range
      // without ':rw'/':ro' leaves writability assumed.
      if (m.source.rfind("probe of ", 0) == 0) {
        r.basis[spec::Fact::read] = basis(spec::Basis::observed, m.source + ": reads answered");
        r.basis[spec::Fact::write] = basis(spec::Basis::observed, m.source + ": not probed, a probe only reads");
      } else if (!b.access) {
        spec::FactBasis assumed = basis(spec::Basis::inferred, m.source + " gives no access: taken as the table allows");
        assumed.searched = m.source;
        r.basis[spec::Fact::write] = assumed;
      }
      s.registers.push_back(std::move(r));
    }
  }
  // A worked sequence goes whole or not at all.
  std::vector<std::string> broken;
  for (const auto& ex : base.examples)
    if (!ex.sequence.empty() && !example_inside(ex, m)) broken.push_back(ex.sequence);
  std::vector<spec::Example> kept;
  for (const auto& ex : base.examples)
    if (example_inside(ex, m) && std::find(broken.begin(), broken.end(), ex.sequence) == broken.end()) kept.push_back(ex);
  s.examples = std::move(kept);
  return s;
}

}  // namespace mbc::conf::map
