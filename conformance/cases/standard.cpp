// Family "standard": the checks MBAP v1.1b3, MB-SL v1.02 and the TCP
// Implementation Guide v1.0b ("TCP IG") make of any server, whatever its map.
// The map only places a request (the first mapped item of a table, the
// address after the last one); the expected answer comes from the clause and
// from the spec's exception policy, and the level from the clause (MUST where
// it states the requirement, SHOULD for the state diagrams' order of checks,
// OBSERVED where it leaves the answer open) and the level rule of
// cases/facts.h. What the other families check already is not repeated here:
// FC 01-04 and 16 quantities and ranges past the map (function-codes), the
// public function codes a profile leaves out (function-codes/unsupported),
// RTU frames and FC 16's short byte count (framing).
//
//   fc05/value-XXXX           FC 05 values other than 0x0000 / 0xFF00 (§6.5)
//   fcNN/byte-count-over      FC 15, 16, 23 byte counts above the quantity's (§6.11, §6.12, §6.17)
//   fcNN/quantity-...         FC 15 and 23 quantities 0 and over the limit (§6.11, §6.17)
//   fcNN/past-map             FC 05, 15, 22, 23 at or through the end of the map (§7 code 02)
//   fc08/...                  FC 08 sub-functions 00 and reserved (serial line only, §6.8)
//   fc43/...                  FC 43 / MEI 14 read device id codes and object ids (§6.21)
//   fc22/mask                 FC 22's result and echo (§6.16)
//   fc23/write-before-read    FC 23 reading the register it writes: the value just written (§6.17)
//   fcNN/reserved             the reserved function codes of MBAP Annex A (§7 code 01)
//   mbap/...                  short and over-long PDUs, protocol id 1, no PDU (TCP IG §3.1.3)
//   order/fcNN                the quantity is checked before the address (SHOULD: the diagrams)
#include <fmt/core.h>

#include <algorithm>

#include "cases/common.h"
#include "cases/facts.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/pdu.h"

namespace mbc::conf {
namespace {

using cases::hex16;
using spec::Table;
using spec::Violation;
using Relies = facts::Relies;
using Touches = std::vector<std::pair<uint16_t, int>>;

// MBAP v1.1b3 Annex A: function codes reserved for legacy products, "not
// available for public use".
constexpr int kReservedCodes[] = {9, 10, 13, 14, 41, 42, 90, 91, 125, 126, 127};

constexpr const char* kCode01 = "MBAP v1.1b3 §7, code 01: \"The function code received in the query is not an allowable action for the server.\"";
constexpr const char* kCode02 =
    "MBAP v1.1b3 §7, code 02: \"The data address received in the query is not an allowable address for the server. More "
    "specifically, the combination of reference number and transfer length is invalid.\"";
constexpr const char* kCode03 =
    "MBAP v1.1b3 §7, code 03: \"A value contained in the query data field is not an allowable value for server. This "
    "indicates a fault in the structure of the remainder of a complex request, such as that the implied length is "
    "incorrect.\"";

Level weaker(Level a, Level b) { return std::max(a, b); }

struct Gen {
  const GenContext& g;
  std::vector<Case>& out;

  Case base(const std::string& group, const std::string& what, const std::string& clause, Level level) {
    Case c;
    c.family = "standard";
    c.id = fmt::format("{}/standard/{}/{}", g.spec.device.id, group, what);
    c.clause = clause;
    c.level = level;
    return c;
  }

  // A case whose answer is the spec's policy for `v`: the clause's level, or
  // OBSERVED where the spec leaves the answer open.
  Case policy_case(const std::string& group, const std::string& what, const std::string& clause, Level level, Violation v,
                   Expect& e) {
    auto pe = cases::policy_expect(g, v);
    Case c = base(group, what, clause + "; " + pe.clause, weaker(level, pe.level));  // pe.expect carries the policy's reliance
    if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
    e = pe.expect;
    return c;
  }

  Step step(Bytes pdu, std::string what, Expect e) const {
    Step s;
    s.unit = g.target.unit;
    s.pdu = std::move(pdu);
    s.note = std::move(what);
    s.expect = std::move(e);
    return s;
  }

  void add(Case c, Step s) {
    c.steps.push_back(std::move(s));
    out.push_back(std::move(c));
  }

  // The first item of `t` the map has (a place for a request whose answer
  // does not depend on the item).
  std::optional<uint16_t> first(Table t) const {
    for (const auto& r : g.spec.registers)
      if (r.table == t) return r.address;
    return std::nullopt;
  }

  // Whether this run may write `r` (a request meant to be refused may be
  // accepted by a server that deviates: it then writes; holding registers
  // are restored through Case::touches).
  bool may_write(const spec::Register* r) const {
    return r && (r->access == spec::Access::rw || r->access == spec::Access::wo) && cases::write_forbidden(g, *r).empty();
  }

  // The first item of `t` this run may write.
  std::optional<uint16_t> writable(Table t) const {
    for (const auto& r : g.spec.registers)
      if (r.table == t && may_write(&r)) return r.address;
    return std::nullopt;
  }

  // The address after the map's last item of `t`, when there is one.
  std::optional<uint16_t> past(Table t) const {
    auto last = g.spec.last_address(t);
    if (!last || *last == 0xFFFF) return std::nullopt;
    return uint16_t(*last + 1);
  }

  // A function code's limit: the spec's, else the standard's (then the
  // case is OBSERVED, as in function-codes).
  std::pair<int, Level> limit(Relies& relies, int fc, const char* which) const {
    if (const auto* f = g.spec.profile.function(fc))
      if (auto q = facts::limit(relies, *f, which)) return {*q, Level::must};
    if (g.standard)
      if (const auto* s = g.standard->profile.function(fc)) {
        Relies ignored;
        if (auto q = facts::limit(ignored, *s, which)) return {*q, Level::observed};
      }
    return {0, Level::observed};
  }

  static Bytes coils_pdu(uint16_t address, uint16_t quantity, size_t bytes) {
    Bytes p = {15, uint8_t(address >> 8), uint8_t(address), uint8_t(quantity >> 8), uint8_t(quantity), uint8_t(bytes)};
    p.resize(p.size() + bytes, 0x00);
    return p;
  }
  static Bytes rw_pdu(uint16_t ra, uint16_t rq, uint16_t wa, uint16_t wq, size_t bytes) {
    Bytes p = {23, uint8_t(ra >> 8), uint8_t(ra), uint8_t(rq >> 8), uint8_t(rq), uint8_t(wa >> 8), uint8_t(wa),
               uint8_t(wq >> 8), uint8_t(wq), uint8_t(bytes)};
    p.resize(p.size() + bytes, 0x00);
    return p;
  }

  void fc05() {
    auto at = writable(Table::coil);
    if (!cases::has_fc(g.spec, 5) || !at) return;
    for (uint16_t v : {0x00FF, 0x0001}) {
      Case c = base("fc05", fmt::format("value-{:04X}", v), "MBAP v1.1b3 §6.5, Figure 15", Level::must);
      c.title = fmt::format("FC 05 to coil {} with the value 0x{:04X}", hex16(*at), v);
      c.requirement = "MBAP v1.1b3 §6.5: \"A value of FF 00 hex requests the output to be ON. A value of 00 00 requests it to be "
                      "OFF. All other values are illegal and will not affect the output.\" " + std::string(kCode03);
      add(std::move(c), step({5, uint8_t(*at >> 8), uint8_t(*at), uint8_t(v >> 8), uint8_t(v)},
                             fmt::format("write coil {} = 0x{:04X} (FC 05)", hex16(*at), v),
                             cases::exception(3, "exception 03: the value is illegal")));
    }
  }

  void byte_counts() {
    auto coil = writable(Table::coil), reg = writable(Table::holding);
    Expect e;
    if (cases::has_fc(g.spec, 15) && coil) {
      Case c = policy_case("fc15", "byte-count-over", "MBAP v1.1b3 §6.11, Figure 21", Level::must, Violation::wrong_byte_count, e);
      c.title = fmt::format("FC 15 for 10 coils at {} with byte count 3 (N = 2)", hex16(*coil));
      c.requirement = "MBAP v1.1b3 §6.11 Figure 21: \"Byte Count == N*\" (N = Quantity / 8, + 1 if the remainder is not 0), "
                      "else exception 03: " + e.text + ".";
      add(std::move(c), step(coils_pdu(*coil, 10, 3), "write multiple coils, quantity 10, byte count 3", e));
    }
    if (cases::has_fc(g.spec, 16) && reg) {
      Case c = policy_case("fc16", "byte-count-over", "MBAP v1.1b3 §6.12, Figure 22", Level::must, Violation::wrong_byte_count, e);
      c.title = fmt::format("FC 16 for 1 register at {} with byte count 3", hex16(*reg));
      c.requirement = "MBAP v1.1b3 §6.12 Figure 22: \"Byte Count == Quantity of Registers x 2\", else exception 03: " + e.text + ".";
      c.touches.push_back({*reg, 1});
      add(std::move(c), step({16, uint8_t(*reg >> 8), uint8_t(*reg), 0, 1, 3, 0, 0, 0},
                             "write multiple registers, quantity 1, byte count 3", e));
    }
    if (cases::has_fc(g.spec, 23) && reg) {
      Case c = policy_case("fc23", "byte-count-over", "MBAP v1.1b3 §6.17, Figure 27", Level::must, Violation::wrong_byte_count, e);
      c.title = fmt::format("FC 23 writing 1 register at {} with byte count 3", hex16(*reg));
      c.requirement = "MBAP v1.1b3 §6.17 Figure 27: \"Byte Count == Quantity of Write x 2\", else exception 03: " + e.text + ".";
      c.touches.push_back({*reg, 1});
      add(std::move(c), step(rw_pdu(*reg, 1, *reg, 1, 3), "read/write multiple registers, write quantity 1, byte count 3", e));
    }
  }

  // Quantity 0 and one over the limit; `pdu(n)` builds the request with quantity n.
  // `touches`: the holding registers a server that deviates would write.
  template <class Build>
  void quantities(int fc, const std::string& which, const char* limit_fact, const std::string& clause, Build pdu,
                  const Touches& touches = {}) {
    Expect e;
    Case z = policy_case(fmt::format("fc{:02}", fc), which + "-0", clause, Level::must, Violation::quantity_zero, e);
    z.touches = touches;
    z.title = fmt::format("FC {:02} with {} 0", fc, which);
    z.requirement = fmt::format("{} 0 is outside 1..N ({}): {}.", which, clause, e.text);
    add(std::move(z), step(pdu(0), fmt::format("FC {:02}, {} 0", fc, which), e));
    Relies relies;
    auto [n, level] = limit(relies, fc, limit_fact);
    if (n <= 0) return;
    Case o = policy_case(fmt::format("fc{:02}", fc), which + "-limit+1", clause, level, Violation::quantity_over_limit, e);
    o.touches = touches;
    for (const auto& r : relies) o.relies.push_back(r);
    o.title = fmt::format("FC {:02} with {} {}, one over the limit", fc, which, n + 1);
    o.requirement = fmt::format("Over the limit of {} ({}): {}.", n, clause, e.text);
    Bytes req = pdu(uint16_t(n + 1));
    if (req.size() > kMaxPdu) {
      o.skip_reason = fmt::format("{} {} does not fit a {}-byte PDU (MBAP v1.1b3 §4.1)", which, n + 1, kMaxPdu);
      out.push_back(std::move(o));
      return;
    }
    add(std::move(o), step(req, fmt::format("FC {:02}, {} {}", fc, which, n + 1), e));
  }

  void quantity_cases() {
    if (auto coil = writable(Table::coil); cases::has_fc(g.spec, 15) && coil)
      quantities(15, "quantity", "max_quantity", "MBAP v1.1b3 §6.11, Figure 21",
                 [&](uint16_t n) { return coils_pdu(*coil, n, (n + 7u) / 8u); });
    if (auto reg = writable(Table::holding); cases::has_fc(g.spec, 23) && reg) {
      quantities(23, "read-quantity", "max_read_quantity", "MBAP v1.1b3 §6.17, Figure 27",
                 [&](uint16_t n) { return rw_pdu(*reg, n, *reg, 1, 2); }, Touches{{*reg, 1}});
      quantities(23, "write-quantity", "max_write_quantity", "MBAP v1.1b3 §6.17, Figure 27",
                 [&](uint16_t n) { return rw_pdu(*reg, 1, *reg, n, size_t(n) * 2); }, Touches{{*reg, 1}});
    }
  }

  void past_map() {
    auto one = [&](int fc, const std::string& what, const std::string& title, Bytes pdu, const Touches& touches = {}) {
      Expect e;
      Case c = policy_case(fmt::format("fc{:02}", fc), what, "MBAP v1.1b3 §7", Level::must, Violation::address_past_map, e);
      c.title = title;
      c.requirement = std::string(kCode02) + " Expected: " + e.text + ".";
      c.touches = touches;
      add(std::move(c), step(std::move(pdu), title, e));
    };
    // A range that runs past the end starts on the last item: a server that
    // deviates writes it, so it must be one this run may write.
    auto last_writable = [&](Table t, std::optional<uint16_t> end) -> std::optional<uint16_t> {
      if (!end || *end == 0 || !may_write(g.spec.register_covering(uint16_t(*end - 1), t))) return std::nullopt;
      return uint16_t(*end - 1);
    };
    auto coil_end = past(Table::coil), reg_end = past(Table::holding);
    auto reg = writable(Table::holding);
    if (cases::has_fc(g.spec, 5) && coil_end)
      one(5, "past-map", fmt::format("FC 05 to coil {}, after the last mapped coil", hex16(*coil_end)), write_single_coil(*coil_end, false));
    if (auto last = last_writable(Table::coil, coil_end); cases::has_fc(g.spec, 15) && last)
      one(15, "runs-past-map", fmt::format("FC 15 from the last coil {} for 2 coils", hex16(*last)), coils_pdu(*last, 2, 1));
    if (cases::has_fc(g.spec, 22) && reg_end)
      one(22, "past-map", fmt::format("FC 22 to {}, after the last mapped register", hex16(*reg_end)), mask_write_register(*reg_end, 0xFFFF, 0));
    if (!cases::has_fc(g.spec, 23) || !reg_end || !reg) return;
    uint16_t last = uint16_t(*reg_end - 1);
    one(23, "read-runs-past-map", fmt::format("FC 23 reading 2 registers from the last one {}", hex16(last)), rw_pdu(last, 2, *reg, 1, 2),
        Touches{{*reg, 1}});
    if (auto w = last_writable(Table::holding, reg_end))
      one(23, "write-runs-past-map", fmt::format("FC 23 writing 2 registers from the last one {}", hex16(*w)), rw_pdu(*reg, 1, *w, 2, 4),
          Touches{{*w, 1}});
  }

  // FC 08 is serial line only (MBAP v1.1b3 §6.8).
  void diagnostics() {
    if (!cases::has_fc(g.spec, 8)) return;
    std::string serial_only = g.target.framing == &mbc::kRtu ? "" : "FC 08 is for serial line only (MBAP v1.1b3 §6.8); the target frames MBAP";
    {
      Case c = base("fc08", "return-query-data", "MBAP v1.1b3 §6.8.1, sub-function 00", Level::must);
      c.title = "FC 08 / 00 Return Query Data with 0xA537";
      c.requirement = "MBAP v1.1b3 §6.8.1: \"The data passed in the request data field is to be returned (looped back) in the response.\"";
      c.skip_reason = serial_only;
      Bytes req = diagnostics_request(0, 0xA537);
      add(std::move(c), step(req, "diagnostics 00, data 0xA537", cases::exact(req, "the request looped back")));
    }
    {
      Expect e;
      Case c = policy_case("fc08", "reserved-subfunction-0013", "MBAP v1.1b3 Annex A; §6.8 Figure 18", Level::should,
                           Violation::unsupported_function, e);
      c.title = "FC 08 with the reserved sub-function 0x0013";
      c.requirement = "MBAP v1.1b3 Annex A reserves FC 08 sub-function 19; Figure 18 answers a sub-function not supported with "
                      "exception 01 (a state diagram: no MUST). " + std::string(kCode01);
      c.skip_reason = serial_only;
      add(std::move(c), step(diagnostics_request(0x13, 0), "diagnostics, sub-function 0x0013", e));
    }
  }

  void identification() {
    const auto* f = g.spec.profile.function(43);
    if (!f || std::find(f->mei_types.begin(), f->mei_types.end(), 14) == f->mei_types.end()) return;
    {
      Case c = base("fc43", "individual-unknown-object", "MBAP v1.1b3 §6.21", Level::must);
      c.title = "FC 43 / 14, individual access (04) to the reserved object 0x7F";
      c.requirement = "MBAP v1.1b3 §6.21: in individual access, \"If the Object Id does not match any known object, the server "
                      "returns an exception response with exception code = 02 (Illegal data address).\"";
      add(std::move(c), step(read_device_identification(4, 0x7F), "read device identification 04, object 0x7F", cases::exception(2)));
    }
    {
      Case c = base("fc43", "stream-unknown-object", "MBAP v1.1b3 §6.21", Level::must);
      c.title = "FC 43 / 14, basic stream access (01) from the reserved object 0x7F";
      c.requirement = "MBAP v1.1b3 §6.21: in stream access, \"If the Object Id does not match any known object, the server "
                      "responds as if object 0 were pointed out (restart at the beginning).\"";
      add(std::move(c), step(read_device_identification(1, 0x7F), "read device identification 01, object 0x7F",
                             cases::normal("a normal reply from object 0")));
    }
    {
      Case c = base("fc43", "bad-read-device-id-code", "MBAP v1.1b3 §6.21, Figure 33", Level::should);
      c.title = "FC 43 / 14 with Read Device ID code 05";
      c.requirement = "MBAP v1.1b3 §6.21: the Read Device ID codes are 01 to 04; the state diagram answers any other with "
                      "exception 03 (no MUST). " + std::string(kCode03);
      add(std::move(c), step(read_device_identification(5, 0), "read device identification, code 05", cases::exception(3)));
    }
  }

  void mask_write() {
    const spec::Register* r = cases::plain_register(g);
    if (!cases::has_fc(g.spec, 22) || !cases::has_fc(g.spec, 6) || !cases::has_fc(g.spec, 3) || !r) return;
    // The worked example of MBAP v1.1b3 §6.16: 0x12 AND 0xF2 OR 0x25 -> 0x17.
    Case c = base("fc22", "mask", "MBAP v1.1b3 §6.16", Level::must);
    c.register_address = r->address;
    c.title = fmt::format("FC 22 on {}: 0x0012 AND 0x00F2 OR 0x0025", hex16(r->address));
    c.requirement = "MBAP v1.1b3 §6.16: \"Result = (Current Contents AND And_Mask) OR (Or_Mask AND (NOT And_Mask))\"; "
                    "\"The normal response is an echo of the request.\"";
    c.touches.push_back({r->address, 1});
    facts::writable(c.relies, *r);
    facts::readable(c.relies, *r);
    const auto& range = facts::range(c.relies, *r);
    if (range && (range->min > 0x12 || range->max < 0x17)) {
      c.skip_reason = fmt::format("{} does not take 0x0012 and 0x0017", hex16(r->address));
      out.push_back(std::move(c));
      return;
    }
    Bytes set = write_single_register(r->address, 0x12);
    Step s = step(set, fmt::format("first: write {} = 0x0012 (FC 06)", hex16(r->address)), cases::write_echo(set));
    s.setup = true;
    c.steps.push_back(std::move(s));
    Bytes mask = mask_write_register(r->address, 0x00F2, 0x0025);
    c.steps.push_back(step(mask, "mask write AND 0x00F2, OR 0x0025", cases::write_echo(mask)));
    Expect want;
    want.kind = Expect::Kind::registers;
    want.words = {0x0017};
    want.text = "0x0017";
    add(std::move(c), *cases::read_step(g, *r, want));
  }

  // MBAP v1.1b3 §6.17: "The write operation is performed before the read."
  // An FC 23 whose read range overlaps its write range reads the values it
  // has just written, not the ones before it.
  void write_before_read() {
    const spec::Register* r = cases::plain_register(g);
    if (!cases::has_fc(g.spec, 23) || !r) return;
    Case c = base("fc23", "write-before-read", "MBAP v1.1b3 §6.17", Level::must);
    c.register_address = r->address;
    c.title = fmt::format("FC 23 reading {} and writing it in the same request", hex16(r->address));
    c.requirement = "MBAP v1.1b3 §6.17: \"This function code performs a combination of one read operation and one write "
                    "operation in a single MODBUS transaction. The write operation is performed before the read.\"";
    c.touches.push_back({r->address, 1});
    cases::plain_relies(c.relies, *r);
    auto [before, after] = cases::plain_values(*r);
    auto wb = cases::encode(*r, before), wa = cases::encode(*r, after);
    auto set = cases::write_step(g, *r, wb);
    if (!set || wb == wa) return;
    set->setup = true;
    set->note = "first: " + set->note;
    c.steps.push_back(std::move(*set));
    Bytes rw = rw_pdu(r->address, 1, r->address, 1, 2);
    rw[10] = uint8_t(wa[0] >> 8);
    rw[11] = uint8_t(wa[0]);
    Bytes want{23, 2, uint8_t(wa[0] >> 8), uint8_t(wa[0])};
    add(std::move(c), step(rw, fmt::format("read {} x1 and write {} = 0x{:04X} (FC 23)", hex16(r->address), hex16(r->address), wa[0]),
                           cases::exact(want, fmt::format("the value just written, 0x{:04X} (the write is performed before "
                                                          "the read)", wa[0]))));
  }

  void reserved() {
    for (int fc : kReservedCodes) {
      if (cases::has_fc(g.spec, fc)) continue;
      Expect e;
      Case c = policy_case(fmt::format("fc{:02}", fc), "reserved", "MBAP v1.1b3 Annex A; §7", Level::must,
                           Violation::unsupported_function, e);
      c.title = fmt::format("FC {:02}, reserved (MBAP v1.1b3 Annex A)", fc);
      c.requirement = fmt::format("Function code {} is reserved for legacy products, \"not available for public use\" (Annex A). {}", fc, kCode01);
      add(std::move(c), step({uint8_t(fc), 0, 0, 0, 1}, fmt::format("FC {:02} with address 0, quantity 1", fc), e));
    }
  }

  // Raw MBAP frames: what a Modbus TCP server does with a malformed header or
  // PDU is not stated (OBSERVED); it must still answer the next good request.
  void mbap() {
    auto reg = first(Table::holding);
    if (!cases::has_fc(g.spec, 3) || !reg) return;
    Bytes good = read_request(3, *reg, 1);
    auto raw_case = [&](const std::string& what, const std::string& title, const std::string& req, Bytes adu, Expect e) {
      Case c = base("mbap", what, "TCP IG v1.0b §3.1.3; " + std::string("MBAP v1.1b3 §7"), Level::observed);
      c.title = title;
      c.requirement = req + " The standard does not state the answer: recorded; the next good request must be answered.";
      if (g.target.framing != &mbc::kTcp) c.skip_reason = "an MBAP case; the target frames RTU (framing/rtu/* checks its frames)";
      else if (!g.target.raw) c.skip_reason = "the target cannot send raw frames";
      Step s;
      s.kind = Step::Kind::raw;
      s.framing = &mbc::kTcp;  // the bytes are an MBAP ADU (TCP IG v1.0b §3.1.3)
      s.bytes = std::move(adu);
      s.note = title;
      s.expect = std::move(e);
      c.steps.push_back(std::move(s));
      c.steps.push_back(step(good, fmt::format("read {} (FC 03), a good request after it", hex16(*reg)), cases::normal()));
      out.push_back(std::move(c));
    };
    Bytes shorter(good.begin(), good.end() - 2), longer = good;
    longer.push_back(0x00);
    raw_case("short-pdu", "FC 03 without its quantity field (MBAP length right)", kCode03, mbap_frame(0x5301, g.target.unit, shorter),
             cases::exception(3, "exception 03: the implied length is incorrect"));
    raw_case("long-pdu", "FC 03 with an extra data byte (MBAP length right)", kCode03, mbap_frame(0x5302, g.target.unit, longer),
             cases::exception(3, "exception 03: the implied length is incorrect"));
    Bytes other = mbap_frame(0x5303, g.target.unit, good);
    other[3] = 0x01;
    raw_case("protocol-id-1", "FC 03 with MBAP protocol id 1",
             "TCP IG v1.0b §3.1.3: \"Protocol Identifier - ... The MODBUS protocol is identified by the value 0.\"", other,
             cases::silence("no Modbus reply: the frame is not Modbus"));
    Bytes empty = mbap_frame(0x5304, g.target.unit, Bytes{});
    raw_case("length-no-pdu", "an MBAP header whose length (1) counts the unit id only: no PDU",
             "TCP IG v1.0b §3.1.3: \"Length - The length field is a byte count of the following fields, including the Unit "
             "Identifier and data fields.\"", empty, Expect{});
  }

  // The state diagrams check the quantity before the address (MBAP v1.1b3
  // Figures 11-14, 21, 22, 27); they carry no MUST.
  void order() {
    auto pz = cases::policy_expect(g, Violation::quantity_over_limit);
    auto pa = cases::policy_expect(g, Violation::address_past_map);
    if (pz.expect.kind == pa.expect.kind && pz.expect.code == pa.expect.code) return;  // the order cannot show
    struct Fc {
      int fc;
      Table t;
      const char* fact;
      const char* figure;
    };
    for (Fc f : {Fc{1, Table::coil, "max_quantity", "Figure 11"}, Fc{2, Table::discrete_input, "max_quantity", "Figure 12"},
                 Fc{3, Table::holding, "max_quantity", "Figure 13"}, Fc{4, Table::input, "max_quantity", "Figure 14"},
                 Fc{15, Table::coil, "max_quantity", "Figure 21"}, Fc{23, Table::holding, "max_read_quantity", "Figure 27"}}) {
      auto end = past(f.t);
      if (!cases::has_fc(g.spec, f.fc) || !end) continue;
      Relies relies;
      auto [n, level] = limit(relies, f.fc, f.fact);
      if (n <= 0) continue;
      Expect e;
      Case c = policy_case("order", fmt::format("fc{:02}-quantity-before-address", f.fc), fmt::format("MBAP v1.1b3 {}", f.figure),
                           weaker(level, Level::should), Violation::quantity_over_limit, e);
      for (const auto& r : relies) c.relies.push_back(r);
      c.title = fmt::format("FC {:02}: quantity {} (over the limit) at {}, past the map", f.fc, n + 1, hex16(*end));
      c.requirement = fmt::format("MBAP v1.1b3 {} tests the quantity before the address: the quantity's answer ({}), not the "
                                  "address's ({}). A state diagram carries no MUST: SHOULD.", f.figure, e.text, pa.expect.text);
      uint16_t q = uint16_t(n + 1);
      auto reg = writable(Table::holding);
      if (f.fc == 23 && !reg) continue;
      if (f.fc == 23) c.touches.push_back({*reg, 1});
      Bytes pdu = f.fc == 15 ? coils_pdu(*end, q, (q + 7u) / 8u) : f.fc == 23 ? rw_pdu(*end, q, *reg, 1, 2) : read_request(uint8_t(f.fc), *end, q);
      if (pdu.size() > kMaxPdu) continue;
      add(std::move(c), step(pdu, fmt::format("FC {:02}, {} items at {}", f.fc, q, hex16(*end)), e));
    }
  }

  void run() {
    fc05();
    byte_counts();
    quantity_cases();
    past_map();
    diagnostics();
    identification();
    mask_write();
    write_before_read();
    reserved();
    mbap();
    order();
  }
};

}  // namespace

std::vector<Case> standard_cases(const GenContext& g) {
  std::vector<Case> out;
  Gen{g, out}.run();
  return out;
}

}  // namespace mbc::conf
