// Family "function-codes": per supported function code, the quantity field at
// 0, 1, the limit and the limit + 1 (the manual's max_quantity, else the
// standard's: MBAP v1.1b3 §6.1-6.4, §6.11, §6.12, then OBSERVED), ranges that
// run past the end of the map or through a gap, and every public function
// code (MBAP v1.1b3 §5.1) the profile does not list.
#include <fmt/core.h>

#include <algorithm>

#include "cases/common.h"
#include "cases/facts.h"
#include "erratum_extra.h"
#include "modbus/function_codes.h"
#include "modbus/limits.h"
#include "modbus/pdu.h"

namespace mbc::conf {
namespace {

using cases::clause;
using cases::hex16;
using spec::Access;
using spec::Register;
using spec::Table;
using spec::Violation;

// MBAP v1.1b3 §5.1 Figure 10: the public function codes, plus two from the
// user-defined ranges 65-72 and 100-110 (§5).
constexpr int kPublicCodes[] = {1, 2, 3, 4, 5, 6, 7, 8, 11, 12, 15, 16, 17, 20, 21, 22, 23, 24, 43, 65, 100};

bool readable(const Register* r) { return r && r->access != Access::wo && r->access != Access::command; }

struct Gen {
  const GenContext& g;
  std::vector<Case>& out;

  Case base(int fc, const std::string& what, const std::string& section) {
    Case c;
    c.family = "function-codes";
    c.id = fmt::format("{}/function-codes/fc{:02}/{}", g.spec.device.id, fc, what);
    c.clause = clause(g.spec, section);
    c.functions_optional = g.map.has_value();  // on a map every function is optional (MBAP v1.1b3 §5.1)
    return c;
  }

  void add(Case c, std::optional<Step> st) {
    if (!st) return;
    c.steps.push_back(std::move(*st));
    out.push_back(std::move(c));
  }

  // The limit the case tests and whether the manual states it.
  std::pair<int, bool> limit_of(const spec::FunctionCode& f, facts::Relies& relies) {
    if (auto q = facts::limit(relies, f, "max_quantity")) return {*q, true};
    if (g.standard)
      if (const auto* s = g.standard->profile.function(f.code); s && s->max_quantity) return {*s->max_quantity, false};
    return {0, false};
  }

  // The first address where `n` consecutive addresses of `t` are all
  // readable: registers the manual states readable first, else any (their
  // `read` facts then go into `relies`).
  std::optional<uint16_t> readable_run(Table t, int n, facts::Relies* relies = nullptr) {
    std::optional<uint16_t> last = g.spec.last_address(t);
    if (!last) return std::nullopt;
    for (bool stated_only : {true, false}) {
      int run = 0;
      std::optional<uint32_t> start;
      for (uint32_t a = 0; a <= *last; ++a) {
        const Register* r = g.spec.register_covering(uint16_t(a), t);
        if (readable(r) && (!stated_only || !spec::demotes(r->basis_of(spec::Fact::read)))) {
          if (run == 0) start = a;
          if (++run < n) continue;
          if (relies)
            for (uint32_t x = *start; x < *start + uint32_t(n); ++x)
              facts::readable(*relies, *g.spec.register_covering(uint16_t(x), t));
          return uint16_t(*start);
        }
        run = 0;
      }
    }
    return std::nullopt;
  }

  // The first unmapped address with mapped registers on both sides, and the
  // readable register just below it.
  std::optional<std::pair<uint16_t, const Register*>> gap(Table t) {
    std::optional<uint16_t> last = g.spec.last_address(t);
    if (!last) return std::nullopt;
    const Register* prev = nullptr;
    for (uint32_t a = 0; a < *last; ++a) {
      const Register* r = g.spec.register_covering(uint16_t(a), t);
      if (r) {
        prev = r;
        continue;
      }
      if (prev && readable(prev) && prev->last_address() + 1 == a) return std::make_pair(uint16_t(a), prev);
    }
    return std::nullopt;
  }

  const Register* last_register(Table t) {
    const Register* last = nullptr;
    for (const auto& r : g.spec.registers)
      if (r.table == t) last = &r;
    return last;
  }

  Case with_policy(Case c, Violation v) {
    auto pe = cases::policy_expect(g, v);
    c.level = pe.level;
    c.clause = pe.clause;
    if (!pe.erratum.empty()) c.errata.push_back(pe.erratum);
    return c;
  }

  void reads(const spec::FunctionCode& f) {
    Table t = spec::table_for_function(f.code);
    facts::Relies lim;
    auto [limit, stated] = limit_of(f, lim);
    facts::Relies first_read;
    std::optional<uint16_t> first = readable_run(t, 1, &first_read);
    if (!first) return;
    {
      auto pe = cases::policy_expect(g, Violation::quantity_zero);
      Case c = with_policy(base(f.code, "quantity-0", f.section), Violation::quantity_zero);
      c.title = fmt::format("FC {:02} with quantity 0", f.code);
      c.requirement = fmt::format("Quantity 0 is outside 1..N (MBAP v1.1b3 §6.{}): {}.", f.code, pe.expect.text);
      add(std::move(c), cases::read_range_step(g, t, *first, 0, pe.expect));
    }
    {
      Case c = base(f.code, "quantity-1", f.section);
      c.title = fmt::format("FC {:02} reads 1 item at {}", f.code, hex16(*first));
      c.requirement = "A read of one mapped, readable item gets a normal reply.";
      c.relies = first_read;
      add(std::move(c), cases::read_range_step(g, t, *first, 1, cases::normal("a normal reply with 1 item")));
    }
    if (limit > 0) {
      Case c = base(f.code, "quantity-limit", f.section);
      c.level = stated ? Level::must : Level::observed;
      c.relies = lim;
      c.title = fmt::format("FC {:02} reads the limit of {} items", f.code, limit);
      c.requirement = stated ? fmt::format("The manual allows up to {} items per request.", limit)
                             : fmt::format("The manual states no limit; the standard's is {}.", limit);
      std::optional<uint16_t> at = readable_run(t, limit, &c.relies);
      if (!at) {
        c.skip_reason = fmt::format("no run of {} consecutive readable addresses in the map", limit);
        out.push_back(std::move(c));
      } else {
        add(std::move(c), cases::read_range_step(g, t, *at, uint16_t(limit), cases::normal(fmt::format("a normal reply with {} items", limit))));
      }
      auto pe = cases::policy_expect(g, Violation::quantity_over_limit);
      Case o = with_policy(base(f.code, "quantity-limit+1", f.section), Violation::quantity_over_limit);
      if (!stated) o.level = Level::observed;
      o.relies = lim;
      o.title = fmt::format("FC {:02} reads {} items, one over the limit", f.code, limit + 1);
      o.requirement = fmt::format("Over the limit of {}: {}.", limit, pe.expect.text);
      // Over readable registers only, where the map has such a run; else the
      // range also covers addresses the map leaves out, and the answer
      // depends on the order of the checks, which only the standard's state
      // diagram gives (MBAP v1.1b3 Figure 13: quantity first; SHOULD, as
      // standard/order/* rates it).
      // modbus-standard is the standard itself: its per-function diagrams
      // state the order (quantity first), so the expectation holds whether
      // or not the items are mapped, and rests on no register's readability.
      bool order_stated = g.standard && g.spec.device.id == g.standard->device.id;
      std::optional<uint16_t> over = readable_run(t, limit + 1, order_stated ? nullptr : &o.relies);
      if (!over && o.level == Level::must && !order_stated) {
        o.level = Level::should;
        o.clause += "; MBAP v1.1b3 §6.3 Figure 13 (the order of the checks)";
        o.requirement += fmt::format(" The {} items from {} also cover addresses the map leaves out, so this relies on the "
                                     "quantity being checked before the addresses (MBAP v1.1b3 Figure 13), which the manual does "
                                     "not state: SHOULD.", limit + 1, hex16(at.value_or(*first)));
      }
      add(std::move(o), cases::read_range_step(g, t, over.value_or(at.value_or(*first)), uint16_t(limit + 1), pe.expect));
    }
    address_cases(f.code, t, [&](uint16_t a, uint16_t n, Expect e) { return cases::read_range_step(g, t, a, n, e); });
  }

  // Past the end of the map and through a gap, for a read or write builder.
  template <class Build>
  void address_cases(int fc, Table t, Build build) {
    if (const Register* last = last_register(t)) {
      auto pe = cases::policy_expect(g, Violation::address_past_map);
      Case c = with_policy(base(fc, "past-map", g.spec.profile.section), Violation::address_past_map);
      uint32_t beyond = last->last_address() + 1;
      if (beyond <= 0xFFFF) {
        c.title = fmt::format("FC {:02} at {}, after the last mapped address", fc, hex16(beyond));
        c.requirement = fmt::format("An address beyond the map: {}.", pe.expect.text);
        add(c, build(uint16_t(beyond), 1, pe.expect));
        if (readable(last) && fc != 6 && fc != 5) {  // a single write cannot run past anything
          Case r = c;
          r.id = fmt::format("{}/function-codes/fc{:02}/runs-past-map", g.spec.device.id, fc);
          r.title = fmt::format("FC {:02} from the last register {} for {} items, one past the map", fc, hex16(last->address), last->words + 1);
          r.requirement = fmt::format("A range that runs past the end of the map: {}.", pe.expect.text);
          add(std::move(r), build(last->address, uint16_t(last->words + 1), pe.expect));
        }
      }
    }
    if (auto gp = gap(t)) {
      auto pe = cases::policy_expect(g, Violation::unmapped_address);
      Case c = with_policy(base(fc, "gap", g.spec.profile.section), Violation::unmapped_address);
      c.title = fmt::format("FC {:02} at {}, a gap in the map", fc, hex16(gp->first));
      c.requirement = fmt::format("An unmapped address inside the map: {}.", pe.expect.text);
      add(c, build(gp->first, 1, pe.expect));
      if (fc <= 4) {
        Case r = c;
        r.id = fmt::format("{}/function-codes/fc{:02}/through-gap", g.spec.device.id, fc);
        r.title = fmt::format("FC {:02} from {} through the gap at {}", fc, hex16(gp->second->address), hex16(gp->first));
        r.requirement = fmt::format("A range that runs through a gap: {}.", pe.expect.text);
        add(std::move(r), build(gp->second->address, uint16_t(gp->second->words + 1), pe.expect));
      }
    }
  }

  // A run of `n` words of consecutive holding registers the case may write
  // whole (starting and ending on register boundaries), with in-range values.
  std::optional<std::pair<uint16_t, std::vector<uint16_t>>> writable_run(int n, facts::Relies* relies = nullptr) {
    std::vector<const Register*> run;
    int words = 0;
    for (const auto& r : g.spec.registers) {
      if (r.table != Table::holding) continue;
      bool ok = r.access == Access::rw && cases::write_forbidden(g, r).empty() && r.type != spec::DataType::f32;
      if (!ok || (!run.empty() && run.back()->last_address() + 1 != r.address)) {
        run.clear();
        words = 0;
        if (!ok) continue;
      }
      run.push_back(&r);
      words += r.words;
      while (words > n) {
        words -= run.front()->words;
        run.erase(run.begin());
      }
      if (words == n) {
        std::vector<uint16_t> values;
        facts::Relies rel;
        for (const Register* x : run) {
          facts::writable(rel, *x);
          const auto& range = facts::range(rel, *x);
          auto dflt = range ? std::nullopt : facts::default_value(rel, *x);
          for (auto w : cases::encode(*x, int64_t(range ? range->min : dflt.value_or(0)))) values.push_back(w);
        }
        if (relies) relies->insert(relies->end(), rel.begin(), rel.end());
        return std::make_pair(run.front()->address, values);
      }
    }
    return std::nullopt;
  }

  void write_multiple(const spec::FunctionCode& f) {
    facts::Relies lim;
    auto [limit, stated] = limit_of(f, lim);
    auto touches = [](uint16_t a, size_t n) { return std::vector<std::pair<uint16_t, int>>{{a, int(n)}}; };
    {
      auto pe = cases::policy_expect(g, Violation::quantity_zero);
      Case c = with_policy(base(16, "quantity-0", f.section), Violation::quantity_zero);
      c.title = "FC 16 with quantity 0 and byte count 0";
      c.requirement = fmt::format("Quantity 0 is outside 1..{} (MBAP v1.1b3 §6.12): {}.", standard_max_quantity(16), pe.expect.text);
      // The register only places the request: quantity 0 is refused before
      // the address is looked at (MBAP v1.1b3 §6.12 Figure 22), so the
      // verdict relies on no fact of it.
      auto run = writable_run(1);
      Step s;
      s.unit = g.target.unit;
      s.pdu = {16, uint8_t(run ? run->first >> 8 : 0), uint8_t(run ? run->first & 0xFF : 0), 0, 0, 0};
      s.note = "write multiple registers, quantity 0";
      s.expect = pe.expect;
      if (run) c.touches = touches(run->first, 1);
      add(std::move(c), s);
    }
    for (int n : {1, limit, limit + 1}) {
      if (n <= 0) continue;
      bool over = n == limit + 1;
      std::string what = n == 1 && limit != 1 ? "quantity-1" : over ? "quantity-limit+1" : "quantity-limit";
      if (n == 1 && limit == 1 && !over) what = "quantity-limit";
      Case c = over ? with_policy(base(16, what, f.section), Violation::quantity_over_limit) : base(16, what, f.section);
      if (n > 1 && !stated) c.level = Level::observed;
      if (n > 1 || over) c.relies = lim;
      auto pe = cases::policy_expect(g, Violation::quantity_over_limit);
      c.title = fmt::format("FC 16 writes {} registers{}", n, over ? ", one over the limit" : n == limit ? " (the limit)" : "");
      c.requirement = over ? fmt::format("Over the limit of {}: {}.", limit, pe.expect.text)
                           : fmt::format("A write of {} in-range registers is accepted (MBAP v1.1b3 §6.12).", n);
      if (2 + 5 + size_t(n) * 2 > kMaxPdu + 1) {
        c.skip_reason = fmt::format("{} registers do not fit a 253-byte PDU (MBAP v1.1b3 §4.1)", n);
        out.push_back(std::move(c));
        continue;
      }
      auto run = writable_run(over ? limit : n, &c.relies);
      if (!run) {
        c.skip_reason = fmt::format("no run of {} consecutive registers this run may write", over ? limit : n);
        out.push_back(std::move(c));
        continue;
      }
      auto words = run->second;
      if (over) words.push_back(words.back());
      c.touches = touches(run->first, words.size());
      Step s;
      s.unit = g.target.unit;
      s.pdu = write_multiple_registers(run->first, words);
      s.note = fmt::format("write {} x{} (FC 16)", hex16(run->first), words.size());
      s.expect = over ? pe.expect : cases::write_echo(s.pdu);
      add(std::move(c), s);
    }
    address_cases(16, Table::holding, [&](uint16_t a, uint16_t n, Expect e) {
      Step s;
      s.unit = g.target.unit;
      std::vector<uint16_t> zeros(n, 0);
      s.pdu = write_multiple_registers(a, zeros);
      s.note = fmt::format("write {} x{} (FC 16)", hex16(a), n);
      s.expect = e;
      return std::optional<Step>(s);
    });
  }

  void write_single(const spec::FunctionCode& f) {
    address_cases(6, Table::holding, [&](uint16_t a, uint16_t, Expect e) {
      Step s;
      s.unit = g.target.unit;
      s.pdu = write_single_register(a, 0);
      s.note = fmt::format("write {} = 0 (FC 06)", hex16(a));
      s.expect = e;
      return std::optional<Step>(s);
    });
  }

  // The request for a function code the profile does not list. A function
  // with no side effect gets its standard request, whole (MBAP v1.1b3 §6.7,
  // 6.9, 6.10, 6.13, 6.14, 6.18, 6.21). Many RTU servers find a frame's end
  // by the length its function code implies rather than by the t3.5 silence
  // of MB-SL v1.02 §2.5.1.1; extra bytes would make such a server wait, or
  // drop the frame for its CRC, and the case would judge its framing rather
  // than its answer to the function code (the framing cases do that). A
  // write keeps address 0 and quantity 1, as before.
  static std::pair<Bytes, std::string> unsupported_request(int code) {
    Request r;
    r.function = uint8_t(code);
    switch (code) {
      case fc::read_exception_status:
      case fc::get_comm_event_counter:
      case fc::get_comm_event_log:
      case fc::report_server_id: return {build_request(r), fmt::format("FC {:02} (no data)", code)};
      case fc::read_file_record:
        r.files = {FileRecord{.reference_type = 6, .file = 1, .record = 0, .length = 1}};
        r.byte_count = 7;  // §6.14: 7 bytes per sub-request
        return {build_request(r), "FC 20 reading record 0 of file 1, 1 word"};
      case fc::read_fifo_queue: return {build_request(r), "FC 24 with FIFO pointer address 0"};
      case fc::encapsulated_interface:
        r.mei_type = kMeiReadDeviceId;
        r.read_device_id_code = 1;
        return {build_request(r), "FC 43 / MEI 14, basic device identification"};
    }
    return {Bytes{uint8_t(code), 0, 0, 0, 1}, fmt::format("FC {:02} with address 0, quantity 1", code)};
  }

  void unsupported() {
    auto pe = cases::policy_expect(g, Violation::unsupported_function);
    for (int fc : kPublicCodes) {
      if (cases::has_fc(g.spec, fc)) continue;
      Case c = with_policy(base(fc, "unsupported", g.spec.profile.section), Violation::unsupported_function);
      c.title = fmt::format("FC {:02}, which the profile does not list", fc);
      c.requirement = fmt::format("A function code the device does not support: {}.", pe.expect.text);
      Step s;
      s.unit = g.target.unit;
      std::tie(s.pdu, s.note) = unsupported_request(fc);
      s.expect = pe.expect;
      if (g.map) {
        // A server on a map chooses which public function codes it implements
        // (MBAP v1.1b3 §5.1): a code the map's spec leaves out is answered
        // either way, never judged by that spec's policy.
        c.functions_optional = false;
        s.expect.kind = Expect::Kind::answered;
        s.expect.text = "a reply, normal or exception: the server chooses which public function codes it implements (MBAP v1.1b3 §5.1)";
        c.requirement = "A server answers every request it receives: with a normal reply, or with an exception (MBAP v1.1b3 §7).";
      }
      add(std::move(c), s);
    }
  }

  void run() {
    for (const auto& f : g.spec.profile.function_codes) {
      if (f.code >= 1 && f.code <= 4) reads(f);
      if (f.code == 16) write_multiple(f);
      if (f.code == 6) write_single(f);
    }
    unsupported();
  }
};

}  // namespace

std::vector<Case> function_code_cases(const GenContext& g) {
  std::vector<Case> out;
  Gen{g, out}.run();
  return out;
}

}  // namespace mbc::conf
