// mbconform fuzz: black-box, structure-aware fuzzing of any target (the
// conf::Target seam: ref:, tcp://, rtu-tcp://, rtu://, plugin:).
//
//   mbconform fuzz --target URI [--device ID] --duration 30s [--out DIR] [--seed S]
//                  [--batch N] [--allow-motion] [--allow-eeprom-writes]
//   mbconform fuzz --replay FILE --target URI [--device ID]
//
// Frames come from the device's spec: reads of its registers, writes of each
// register's valid and boundary values, the manual's example requests, and
// those frames with one field mutated (function code, address, quantity,
// byte count, value, length); with raw access (TargetInfo::raw) also
// malformed framing (bad CRC, truncated, over-long, another slave id,
// broadcast, an inter-character gap). Every reply is judged from the standard
// (judge_reply, the RTU framing) and after each batch a liveness probe
// (a read of a register the spec maps) must be answered normally.
//
// A finding (no answer, a malformed answer, an answer to another slave id or
// to broadcast, the target failing) is reduced by delta debugging on fresh
// targets to a minimal sequence of frames, saved as hex in DIR, and the
// command that replays it is printed. Exit 0: nothing found; 1: a finding;
// 2: could not run.
//
// Safety with live drives (conformance/safety/safety.h): writes only to
// registers may_write() allows (command and motion registers need
// --allow-motion, persistent ones --allow-eeprom-writes), the registers are
// snapshotted first and restored afterwards; nothing ever writes the serial
// settings (slave id, baud rate) or the "do not persist" switch; on live
// targets writes go only to registers the spec maps, never to mutated
// addresses, and broadcast / other-slave frames only read.
#include <fmt/core.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstring>
#include <functional>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>

#include "commands.h"
#include "report/report.h"
#include "loader.h"
#include "modbus/bytes.h"
#include "modbus/crc16.h"
#include "modbus/judge.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"
#include "safety/safety.h"
#include "spec_values.h"
#include "targets/target.h"

namespace mbc::cli {
namespace {

namespace fs = std::filesystem;
using spec::Access;
using spec::Register;
using spec::Table;

// ---- steps: what the fuzzer does, one line each in a reproducer ----

struct Step {
  enum class Kind { pdu, raw, probe, advance } kind = Kind::pdu;
  uint8_t unit = 0;                // pdu, probe
  Bytes bytes;                     // pdu / probe: a PDU; raw: the ADU as sent
  std::optional<size_t> gap;       // raw: inter-character gap after this many bytes
  uint64_t us = 0;                 // advance
};

std::string to_line(const Step& s) {
  switch (s.kind) {
    case Step::Kind::pdu: return fmt::format("pdu {} {}", s.unit, to_hex(s.bytes));
    case Step::Kind::probe: return fmt::format("probe {} {}", s.unit, to_hex(s.bytes));
    case Step::Kind::raw: return s.gap ? fmt::format("raw@{} {}", *s.gap, to_hex(s.bytes)) : fmt::format("raw {}", to_hex(s.bytes));
    case Step::Kind::advance: return fmt::format("advance {}", s.us);
  }
  return "";
}

std::optional<Step> parse_line(const std::string& line) {
  std::istringstream in(line);
  std::string word;
  if (!(in >> word) || word[0] == '#') return std::nullopt;
  Step s;
  std::string rest;
  auto tail = [&] {
    std::getline(in, rest);
    return parse_hex(rest);
  };
  if (word == "pdu" || word == "probe") {
    int unit = -1;
    in >> unit;
    auto b = tail();
    if (unit < 0 || unit > 255 || !b || b->empty()) throw std::invalid_argument("bad line: " + line);
    s.kind = word == "pdu" ? Step::Kind::pdu : Step::Kind::probe;
    s.unit = uint8_t(unit);
    s.bytes = *b;
  } else if (word.rfind("raw", 0) == 0) {
    s.kind = Step::Kind::raw;
    if (word.size() > 4 && word[3] == '@') s.gap = size_t(std::stoul(word.substr(4)));
    auto b = tail();
    if (!b) throw std::invalid_argument("bad line: " + line);
    s.bytes = *b;
  } else if (word == "advance") {
    s.kind = Step::Kind::advance;
    in >> s.us;
  } else {
    throw std::invalid_argument("unknown step '" + word + "' (pdu, probe, raw, raw@N, advance)");
  }
  return s;
}

struct Finding {
  std::string kind;     // stable name: no-answer, malformed-reply, ...
  std::string message;  // what was sent, what came, why it is wrong
};

// ---- what the spec and the safety rules allow ----

struct Plan {
  const spec::Spec* spec = nullptr;
  conf::TargetInfo info;
  bool allow_motion = false, allow_eeprom = false;
  std::vector<const Register*> readable, writable;
  std::set<uint16_t> forbidden;  // holding addresses no write may touch
  std::vector<Bytes> examples;   // example request PDUs that pass the safety rules
  std::vector<uint8_t> functions;
  Bytes probe;

  bool writable_register(const Register& r) const {
    if (r.access == Access::ro || r.table == Table::input || r.table == Table::discrete_input) return false;
    for (const auto& st : spec->serial.settings)
      if (st.register_address >= r.address && st.register_address <= r.last_address()) return false;
    if (forbidden.count(r.address)) return false;
    return conf::may_write(*spec, r, info, policy()).allowed;  // a simulation (not live) allows everything
  }
  conf::WritePolicy policy() const { return conf::WritePolicy{allow_motion, allow_eeprom}; }

  // Whether a request PDU may be sent to unit `unit` (0 = broadcast).
  bool safe(std::span<const uint8_t> pdu, bool foreign_or_broadcast) const {
    if (pdu.empty()) return true;
    uint8_t fc = pdu[0];
    // MB-SL v1.02 §6.1.2 (FC 08/04): Listen Only Mode is a legal way to stop
    // answering; the liveness probe would call it a finding.
    if (fc == 8 && pdu.size() >= 3 && be16(pdu, 1) == 4) return false;
    bool write = fc == 5 || fc == 6 || fc == 15 || fc == 16 || fc == 22 || fc == 23;
    if (info.live) {
      // Only function codes the spec lists or the standard defines as reads:
      // a vendor may put anything behind an undocumented code.
      static const std::set<uint8_t> standard_reads{1, 2, 3, 4, 7, 11, 12, 17, 20, 24, 43};
      if (!standard_reads.count(fc) && !spec->profile.function(fc) && !(fc & 0x80)) return false;
      if (fc == 8 && (pdu.size() < 3 || be16(pdu, 1) != 0)) return false;  // only Return Query Data
      if (write && foreign_or_broadcast) return false;  // other drives on the bus have other maps
    }
    if (!write || pdu.size() < 5) return true;
    uint32_t start = be16(pdu, 1), count = 1;
    if (fc == 15 || fc == 16) count = be16(pdu, 3);
    if (fc == 23) {
      if (pdu.size() < 9) return true;
      start = be16(pdu, 5);
      count = be16(pdu, 7);
    }
    Table t = fc == 5 || fc == 15 ? Table::coil : Table::holding;
    if (count == 0) return true;
    if (!info.live) {
      if (t != Table::holding) return true;
      for (uint32_t a = start; a < start + count && a <= 0xFFFF; ++a)
        if (forbidden.count(uint16_t(a))) return false;
      return true;
    }
    // Live: every word written must belong to a register the rules allow.
    if (count > 125) return false;  // beyond the standard's limits: only a malformed request is safe to leave out
    for (uint32_t a = start; a < start + count; ++a) {
      if (a > 0xFFFF) return false;
      const Register* r = spec->register_covering(uint16_t(a), t);
      if (!r || !writable_register(*r)) return false;
    }
    return true;
  }
};

Plan make_plan(const spec::Spec& s, const conf::TargetInfo& info, bool allow_motion, bool allow_eeprom) {
  Plan p;
  p.spec = &s;
  p.info = info;
  p.allow_motion = allow_motion;
  p.allow_eeprom = allow_eeprom;
  for (const auto& st : s.serial.settings) p.forbidden.insert(st.register_address);
  // The "do not persist" switch (57HS-R 0x0016) stays as Snapshot::take set it.
  for (const auto& r : s.registers)
    if (r.persistence.unless_register) p.forbidden.insert(*r.persistence.unless_register);
  for (const Register* r : fuzz::representative_registers(s)) {
    if (r->access != Access::wo && s.profile.function(fuzz::read_function(r->table))) p.readable.push_back(r);
    if (p.writable_register(*r)) p.writable.push_back(r);
  }
  for (const auto& f : s.profile.function_codes) p.functions.push_back(uint8_t(f.code));
  for (const auto& ex : s.examples) {
    auto adu = parse_hex(ex.resolved_request ? *ex.resolved_request : ex.request);
    if (!adu || adu->size() < 4) continue;
    Bytes pdu(adu->begin() + 1, adu->end() - 2);
    if (p.safe(pdu, false)) p.examples.push_back(pdu);
  }
  // The probe: a read of the first holding register (else any register) the
  // spec maps and the profile can read: a known-good request.
  const Register* probe = nullptr;
  for (const Register* r : p.readable)
    if (!probe || (r->table == Table::holding && probe->table != Table::holding)) probe = r;
  if (!probe) throw std::runtime_error("spec " + s.device.id + " maps no register the profile can read: no liveness probe");
  p.probe = read_request(fuzz::read_function(probe->table), probe->address, uint16_t(probe->words));
  return p;
}

// ---- judging one exchange (from the standard, never from an implementation) ----

bool exception_code_known(const spec::Spec& s, uint8_t code) {
  if (code >= 1 && code <= 4) return true;  // MBAP v1.1b3 §7
  for (const auto& e : s.profile.exception_codes)
    if (e.code == code) return true;
  for (const auto& [k, pe] : s.profile.exception_policy)
    if (pe.kind == spec::PolicyEntry::Kind::exception && pe.code == code) return true;
  return false;
}

std::optional<Finding> judge(const Plan& p, const Step& st, const conf::Reply& r) {
  auto f = [&](std::string kind, std::string why) {
    std::string m = fmt::format("{}\n  sent:  {}\n  reply: {}", why, to_hex(r.request),
                                r.silent() ? std::string("(silence)") : to_hex(r.frame));
    if (r.pdu) m += "  (" + describe_pdu(*r.pdu, false) + ")";
    return Finding{std::move(kind), m};
  };
  const spec::Spec& s = *p.spec;
  std::span<const uint8_t> req;
  bool addressed = true, framing_valid = true;
  if (st.kind == Step::Kind::raw) {
    // A gap splits the bytes into two frames for the receiver (MB-SL v1.02
    // §2.5.1.1); either part may happen to be a valid frame of its own.
    std::vector<std::span<const uint8_t>> parts;
    std::span<const uint8_t> all(st.bytes);
    if (st.gap && *st.gap < all.size()) parts = {all.first(*st.gap), all.subspan(*st.gap)};
    else parts = {all};
    framing_valid = false;
    addressed = false;
    for (auto a : parts) {
      bool valid = a.size() >= 4 && a.size() <= 256 && crc_ok(a);
      if (!a.empty() && a[0] == p.info.unit && (!addressed || (valid && !framing_valid))) {
        addressed = true;
        framing_valid = valid;
        if (a.size() >= 4) req = a.subspan(1, a.size() - 3);
      }
    }
  } else {
    addressed = st.unit != 0;
    req = st.bytes;
  }
  if (!r.silent()) {
    if (!addressed)
      return f(st.kind == Step::Kind::raw && !st.bytes.empty() && st.bytes[0] != 0 ? "answered-other-slave" : "answered-broadcast",
               "a reply to a frame for another slave id or to broadcast (MB-SL v1.02 §2.1: no response)");
    if (!r.framing_error.empty()) return f("malformed-framing", r.framing_error);
    if (!framing_valid) {
      // Only a device whose manual says it answers corrupted frames may (its crc_error policy).
      auto pe = s.profile.policy(spec::Violation::crc_error);
      if (pe.kind != spec::PolicyEntry::Kind::exception || !r.pdu || r.pdu->size() != 2 || !((*r.pdu)[0] & 0x80))
        return f("answered-corrupted-frame", "a reply to a frame with a bad CRC, length or gap (MB-SL v1.02 §2.4.2: no response)");
      return std::nullopt;
    }
    if (r.pdu) {
      Judged j = judge_reply(req, *r.pdu);
      if (!j.ok()) {
        std::string why = "reply malformed for the request:";
        for (const auto& pr : j.problems) why += " " + pr + ";";
        return f("malformed-reply", why);
      }
      if (j.kind == Judged::Kind::exception && !exception_code_known(s, j.exception_code))
        return f("unknown-exception-code",
                 fmt::format("exception code {:02X} is neither in MBAP v1.1b3 §7 nor in the spec", j.exception_code));
      if (st.kind == Step::Kind::probe && j.kind != Judged::Kind::normal)
        return f("probe-refused", "the liveness probe (a read of a register the spec maps) was refused");
    }
  } else if (st.kind == Step::Kind::probe) {
    return f("no-answer", "the target stopped answering: no reply to the liveness probe (a read of a register the spec maps)");
  }
  return std::nullopt;
}

// Runs one step; a target that throws (connection lost, plugin error) is a finding too.
std::optional<Finding> execute(conf::Target& t, const Plan& p, const Step& st) {
  try {
    conf::Reply r;
    switch (st.kind) {
      case Step::Kind::advance: t.advance(std::chrono::microseconds(st.us)); return std::nullopt;
      case Step::Kind::raw: r = t.send_raw(st.bytes, st.gap); break;
      case Step::Kind::pdu:
      case Step::Kind::probe: r = t.transact(st.unit, st.bytes); break;
    }
    if (auto f = judge(p, st, r); f) return f;
    if (st.kind == Step::Kind::probe && r.silent()) return Finding{"no-answer", "no reply to the probe"};
  } catch (const std::exception& e) {
    return Finding{"target-error", fmt::format("the target failed: {}\n  step: {}", e.what(), to_line(st))};
  }
  return std::nullopt;
}

// ---- generating steps ----

class Generator {
 public:
  Generator(const Plan& p, uint64_t seed) : p_(p), rng_(seed) {}

  Step next() {
    const auto& info = p_.info;
    if (info.virtual_clock && pick(20) == 0) return Step{Step::Kind::advance, 0, {}, {}, uint64_t(pick(500'000))};
    for (int attempt = 0; attempt < 20; ++attempt) {
      int strategy = int(pick(info.raw ? 5 : 4));
      Bytes pdu;
      switch (strategy) {
        case 0: pdu = valid_read(); break;
        case 1: pdu = boundary_write(); break;
        case 2: pdu = mutate(base()); break;
        case 3: pdu = p_.examples.empty() ? valid_read() : p_.examples[pick(p_.examples.size())]; break;
        case 4: {
          Bytes b = base();
          if (pick(2)) b = mutate(b);
          if (auto s = malformed(b)) return *s;
          continue;
        }
      }
      if (pdu.empty() || pdu.size() > 253 || !p_.safe(pdu, false)) continue;
      return Step{Step::Kind::pdu, info.unit, pdu, {}, 0};
    }
    return Step{Step::Kind::pdu, info.unit, valid_read(), {}, 0};
  }

 private:
  uint64_t pick(uint64_t n) { return n ? rng_() % n : 0; }
  const Register& any(const std::vector<const Register*>& v) { return *v[pick(v.size())]; }

  Bytes valid_read() {
    if (p_.readable.empty()) return p_.probe;
    const Register& r = any(p_.readable);
    uint8_t fc = fuzz::read_function(r.table);
    const auto* f = p_.spec->profile.function(fc);
    int max = f && f->max_quantity ? *f->max_quantity : 8;
    uint16_t q = uint16_t(pick(4) ? r.words : 1 + pick(uint64_t(std::min(max, 16))));
    return read_request(fc, r.address, q);
  }

  Bytes boundary_write() {
    if (p_.writable.empty()) return valid_read();
    const Register& r = any(p_.writable);
    auto values = fuzz::boundary_values(*p_.spec, r);
    if (values.empty()) return valid_read();
    auto pdus = fuzz::write_pdus(*p_.spec, r, values[pick(values.size())]);
    return pdus.empty() ? valid_read() : pdus[pick(pdus.size())];
  }

  Bytes base() {
    switch (pick(3)) {
      case 0: return valid_read();
      case 1: return boundary_write();
      default: return p_.examples.empty() ? valid_read() : p_.examples[pick(p_.examples.size())];
    }
  }

  uint16_t interesting16(uint16_t near) {
    static const uint16_t values[] = {0, 1, 0x7D, 0x7E, 0x7B, 0x7C, 0x7D0, 0x7D1, 0x7B0, 0x7B1, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFF00, 0xFFFE, 0xFFFF};
    switch (pick(4)) {
      case 0: return values[pick(std::size(values))];
      case 1: return uint16_t(near + pick(3) - 1);
      case 2: {
        auto last = p_.spec->last_address(Table::holding);
        return last ? uint16_t(*last + 1) : 0;
      }
      default: return uint16_t(rng_());
    }
  }

  // One field of a well-formed request changed (MBAP v1.1b3 §6 field layout).
  Bytes mutate(Bytes pdu) {
    if (pdu.empty()) return pdu;
    switch (pick(8)) {
      case 0: {  // function code
        if (pick(2) && !p_.functions.empty()) pdu[0] = p_.functions[pick(p_.functions.size())];
        else pdu[0] = uint8_t(pick(p_.info.live ? 0x80 : 0x100));
        break;
      }
      case 1:  // address
        if (pdu.size() >= 3) {
          uint16_t a = interesting16(be16(pdu, 1));
          pdu[1] = uint8_t(a >> 8), pdu[2] = uint8_t(a);
        }
        break;
      case 2:  // quantity or value
        if (pdu.size() >= 5) {
          uint16_t q = interesting16(be16(pdu, 3));
          pdu[3] = uint8_t(q >> 8), pdu[4] = uint8_t(q);
        }
        break;
      case 3:  // byte count of FC 15/16 (offset 5) and FC 23 (offset 9)
        if ((pdu[0] == 15 || pdu[0] == 16) && pdu.size() >= 6) pdu[5] = uint8_t(rng_());
        else if (pdu[0] == 23 && pdu.size() >= 10) pdu[9] = uint8_t(rng_());
        else if (pdu.size() >= 2) pdu[1 + pick(pdu.size() - 1)] = uint8_t(rng_());
        break;
      case 4: pdu.resize(1 + pick(pdu.size())); break;  // truncated
      case 5: {                                         // trailing bytes
        size_t n = 1 + pick(8);
        for (size_t i = 0; i < n; ++i) pdu.push_back(uint8_t(rng_()));
        break;
      }
      case 6:  // one bit
        pdu[pick(pdu.size())] ^= uint8_t(1u << pick(8));
        break;
      default:  // a longer write: more registers than the profile allows
        if (pdu[0] == 16 && pdu.size() >= 6) {
          uint16_t q = uint16_t(1 + pick(127));
          Bytes b{16, pdu[1], pdu[2], uint8_t(q >> 8), uint8_t(q), uint8_t(2 * q)};
          for (int i = 0; i < 2 * q && b.size() < 253; ++i) b.push_back(uint8_t(rng_()));
          pdu = b;
        }
        break;
    }
    return pdu;
  }

  // Malformed framing (MB-SL v1.02 §2.5.1): the frame a correct device drops.
  std::optional<Step> malformed(const Bytes& pdu) {
    // Over Modbus TCP the frame is the MBAP header's business: RTU bytes would
    // only desynchronise the stream. On a byte stream without timing (TCP,
    // RTU over TCP) a frame whose length is wrong swallows the next request
    // (its end is found by counting bytes), so only length-keeping faults.
    if (p_.info.framing != conf::Framing::rtu) return std::nullopt;
    const bool stream = p_.info.kind == "tcp" || p_.info.kind == "rtu-tcp";
    uint8_t unit = p_.info.unit;
    Step s{Step::Kind::raw, unit, rtu_frame(unit, pdu), {}, 0};
    Bytes& a = s.bytes;
    static const int kStreamCases[] = {0, 3, 4};
    switch (stream ? kStreamCases[pick(3)] : int(pick(6))) {
      case 0: a[a.size() - 1 - pick(2)] ^= uint8_t(1u << pick(8)); break;  // CRC
      case 1: a.resize(1 + pick(a.size() - 1)); break;                       // truncated
      case 2: {                                                              // over 256 bytes
        while (a.size() < 257 + pick(40)) a.push_back(uint8_t(rng_()));
        break;
      }
      case 3: {  // another slave id, CRC right: must be silent
        uint8_t other = uint8_t(1 + pick(247));
        if (other == unit) other = uint8_t(unit % 247 + 1);
        if (!p_.safe(pdu, true)) return std::nullopt;
        a = rtu_frame(other, pdu);
        break;
      }
      case 4: {  // broadcast, CRC right: executed (writes) but never answered
        if (!p_.safe(pdu, true) || !p_.spec->serial.broadcast_address) return std::nullopt;
        a = rtu_frame(uint8_t(*p_.spec->serial.broadcast_address), pdu);
        break;
      }
      default:  // a pause of more than t1.5 inside the frame (§2.5.1.1): two broken frames
        if (a.size() < 2) return std::nullopt;
        s.gap = 1 + pick(a.size() - 1);
        break;
    }
    if (!p_.safe(pdu, false)) return std::nullopt;
    return s;
  }

  const Plan& p_;
  std::mt19937_64 rng_;
};

// ---- running and reducing ----

using Open = std::function<std::unique_ptr<conf::Target>()>;

// Runs `steps` on a fresh target; the first finding, if any.
// A target that cannot be opened again (a server that died) reproduces nothing.
std::optional<Finding> run_fresh(const Open& open, const Plan& p, const std::vector<Step>& steps) {
  std::unique_ptr<conf::Target> t;
  try {
    t = open();
  } catch (const std::exception& e) {
    return Finding{"cannot-reopen", e.what()};
  }
  for (const auto& st : steps)
    if (auto f = execute(*t, p, st)) return f;
  return std::nullopt;
}

// A plugin runs inside this process: a crash in it must not take the fuzzer
// down. Runs `fn` in a child; a child killed by a signal is a "crash" finding.
std::optional<Finding> isolated(const std::function<std::optional<Finding>()>& fn) {
  int fds[2];
  if (pipe(fds) != 0) return fn();
  std::fflush(nullptr);
  pid_t pid = fork();
  if (pid < 0) return fn();
  if (pid == 0) {
    close(fds[0]);
    auto f = fn();
    std::string out = f ? f->kind + "\n" + f->message : "";
    (void)!write(fds[1], out.data(), out.size());
    _exit(0);
  }
  close(fds[1]);
  std::string got;
  char buf[4096];
  for (ssize_t n; (n = read(fds[0], buf, sizeof buf)) > 0;) got.append(buf, size_t(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (WIFSIGNALED(status))
    return Finding{"crash", fmt::format("the target's process died with signal {} ({})", WTERMSIG(status), strsignal(WTERMSIG(status)))};
  if (got.empty()) return std::nullopt;
  auto nl = got.find('\n');
  return Finding{got.substr(0, nl), nl == std::string::npos ? "" : got.substr(nl + 1)};
}

struct Reducer {
  const Open& open;
  const Plan& plan;
  bool isolate;
  std::string kind;
  int budget = 400;  // fresh-target runs; each costs a connection on live targets
  int runs = 0;

  bool fails(const std::vector<Step>& steps) {
    ++runs;
    auto f = isolate ? isolated([&] { return run_fresh(open, plan, steps); }) : run_fresh(open, plan, steps);
    return f && f->kind == kind;
  }

  // ddmin (Zeller & Hildebrandt 2002) over the steps, within the budget.
  std::vector<Step> minimize(std::vector<Step> steps) {
    size_t n = 2;
    while (steps.size() >= 2 && runs < budget) {
      size_t chunk = (steps.size() + n - 1) / n;
      bool reduced = false;
      for (size_t i = 0; i < steps.size() && runs < budget; i += chunk) {
        std::vector<Step> complement(steps.begin(), steps.begin() + long(i));
        complement.insert(complement.end(), steps.begin() + long(std::min(steps.size(), i + chunk)), steps.end());
        if (!complement.empty() && fails(complement)) {
          steps = std::move(complement);
          n = std::max<size_t>(n - 1, 2);
          reduced = true;
          break;
        }
      }
      if (!reduced) {
        if (n >= steps.size()) break;
        n = std::min(n * 2, steps.size());
      }
    }
    return steps;
  }
};

fs::path save_reproducer(const fs::path& dir, const std::string& uri, const std::string& device, const Finding& f,
                         const std::vector<Step>& steps) {
  fs::create_directories(dir);
  fs::path file;
  for (int i = 1;; ++i) {
    file = dir / fmt::format("finding-{}-{}.txt", f.kind, i);
    if (!fs::exists(file)) break;
  }
  std::ofstream out(file);
  out << "# mbconform fuzz reproducer: replay with\n#   mbconform fuzz --replay " << file.string() << " --target '" << uri
      << "' --device " << device << "\n";
  out << "# finding: " << f.kind << "\n";
  std::istringstream msg(f.message);
  for (std::string line; std::getline(msg, line);) out << "#   " << line << "\n";
  out << "# steps: pdu UNIT HEX (a request PDU), probe UNIT HEX (a read that must be answered),\n"
         "#        raw HEX (an ADU as sent), raw@N HEX (a gap after N bytes), advance MICROSECONDS\n";
  for (const auto& st : steps) out << to_line(st) << "\n";
  return file;
}

std::optional<std::chrono::milliseconds> parse_duration(const std::string& text) {
  size_t used = 0;
  double v = 0;
  try {
    v = std::stod(text, &used);
  } catch (...) {
    return std::nullopt;
  }
  std::string unit = text.substr(used);
  double ms = unit == "ms" ? v : unit == "" || unit == "s" ? v * 1e3 : unit == "m" ? v * 60e3 : unit == "h" ? v * 3600e3 : -1;
  if (ms < 0 || v < 0) return std::nullopt;
  return std::chrono::milliseconds(int64_t(ms));
}

struct FuzzArgs {
  std::string target, device, duration = "10s", out = "fuzz-findings", replay;
  std::optional<uint64_t> seed;
  int batch = 50;
  bool allow_motion = false, allow_eeprom = false;
};

constexpr size_t kHistoryCap = 20000;

int run_fuzz(const FuzzArgs& a) {
  if (!conf::out_dir_ok(a.out, "mbconform fuzz")) return kExitUsage;
  std::unique_ptr<conf::Target> target;
  try {
    target = conf::open_target(a.target);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbconform fuzz: %s\n", e.what());
    return kExitUsage;
  }
  conf::TargetInfo info = target->info();
  std::string device = a.device.empty() ? info.device_id : a.device;
  if (device.empty()) {
    std::fprintf(stderr, "mbconform fuzz: --device ID is needed for target %s (which spec describes it?)\n", info.uri.c_str());
    return kExitUsage;
  }
  spec::Spec s;
  Plan plan;
  try {
    s = spec::load_spec_by_id(device);
    plan = make_plan(s, info, a.allow_motion, a.allow_eeprom);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbconform fuzz: %s\n", e.what());
    return kExitUsage;
  }
  const std::string uri = a.target;
  Open open = [&] { return conf::open_target(uri); };
  const bool isolate = info.kind == "plugin";

  if (!a.replay.empty()) {
    std::ifstream in(a.replay);
    if (!in) {
      std::fprintf(stderr, "mbconform fuzz: cannot read %s\n", a.replay.c_str());
      return kExitUsage;
    }
    std::vector<Step> steps;
    try {
      for (std::string line; std::getline(in, line);)
        if (auto st = parse_line(line)) steps.push_back(*st);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "mbconform fuzz: %s: %s\n", a.replay.c_str(), e.what());
      return kExitUsage;
    }
    target.reset();
    auto f = isolate ? isolated([&] { return run_fresh(open, plan, steps); }) : run_fresh(open, plan, steps);
    if (f) {
      std::printf("reproduced: %s: %s\n", f->kind.c_str(), f->message.c_str());
      return kExitFailed;
    }
    std::printf("%zu steps replayed on %s: no finding\n", steps.size(), info.uri.c_str());
    return kExitOk;
  }

  auto duration = parse_duration(a.duration);
  if (!duration) {
    std::fprintf(stderr, "mbconform fuzz: --duration '%s': expected e.g. 500ms, 20s, 5m, 1h\n", a.duration.c_str());
    return kExitUsage;
  }
  // A live drive gets back the values it had (conformance/safety/safety.h).
  std::optional<conf::Snapshot> snapshot;
  if (info.live) {
    snapshot = conf::Snapshot::take(*target, s, plan.policy());
    for (const auto& f : snapshot->failures()) std::fprintf(stderr, "mbconform fuzz: snapshot: %s\n", f.c_str());
  }
  auto restore = [&] {
    if (!snapshot) return;
    try {
      auto t = open();
      for (const auto& f : snapshot->restore(*t)) std::fprintf(stderr, "mbconform fuzz: NOT RESTORED: %s\n", f.c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "mbconform fuzz: could not restore the drive's registers: %s\n", e.what());
    }
  };
  uint64_t seed = a.seed.value_or(uint64_t(std::chrono::steady_clock::now().time_since_epoch().count()));
  std::printf("fuzzing %s as %s for %s, seed %llu, batches of %d frames (%zu readable, %zu writable registers)\n",
              info.uri.c_str(), device.c_str(), a.duration.c_str(), (unsigned long long)seed, a.batch,
              plan.readable.size(), plan.writable.size());
  std::fflush(stdout);

  // The fuzz loop. Its history is every step since the target was opened, so a
  // finding that needs earlier state can be reproduced on a fresh target.
  std::vector<Step> history;
  size_t last_probe = 0;
  long frames = 0, batches = 0;
  auto loop = [&]() -> std::optional<Finding> {
    Generator gen(plan, seed);
    Step probe{Step::Kind::probe, info.unit, plan.probe, {}, 0};
    history.push_back(probe);
    if (auto f = execute(*target, plan, probe)) return f;
    auto deadline = std::chrono::steady_clock::now() + *duration;
    while (std::chrono::steady_clock::now() < deadline) {
      // A bounded history: findings that need state older than this are
      // reported with what is kept (and said not to reproduce, if so).
      if (history.size() > kHistoryCap) {
        size_t drop = history.size() - kHistoryCap / 2;
        history.erase(history.begin(), history.begin() + long(drop));
      }
      last_probe = history.size();
      for (int i = 0; i < a.batch; ++i) {
        Step st = gen.next();
        history.push_back(st);
        ++frames;
        if (auto f = execute(*target, plan, st)) return f;
      }
      history.push_back(probe);
      ++batches;
      if (auto f = execute(*target, plan, probe)) return f;
    }
    return std::nullopt;
  };

  std::optional<Finding> finding;
  if (isolate) {
    // The loop in a child, so a plugin crash cannot lose it: the child
    // journals each step before sending it; the parent reduces the journal.
    fs::create_directories(a.out);
    fs::path journal = fs::path(a.out) / ".journal";
    finding = isolated([&]() -> std::optional<Finding> {
      std::ofstream j(journal, std::ios::trunc);
      Generator gen(plan, seed);
      Step probe{Step::Kind::probe, info.unit, plan.probe, {}, 0};
      auto deadline = std::chrono::steady_clock::now() + *duration;
      std::vector<Step> steps{probe};
      while (std::chrono::steady_clock::now() < deadline) {
        for (int i = 0; i < a.batch; ++i) steps.push_back(gen.next());
        steps.push_back(probe);
        for (size_t i = steps.size() - size_t(a.batch) - 1; i < steps.size(); ++i) {
          j << to_line(steps[i]) << std::endl;
          if (auto f = execute(*target, plan, steps[i])) return f;
        }
      }
      return std::nullopt;
    });
    std::ifstream in(journal);
    for (std::string line; std::getline(in, line);)
      if (auto st = parse_line(line)) history.push_back(*st);
    fs::remove(journal);
    last_probe = 0;
  } else {
    finding = loop();
  }
  target.reset();

  if (!finding) {
    restore();
    std::printf("no finding: %ld frames in %ld batches, every probe answered\n", frames, batches);
    return kExitOk;
  }
  std::printf("FINDING %s after %zu steps: %s\n", finding->kind.c_str(), history.size(), finding->message.c_str());
  std::fflush(stdout);

  // Reduce: the last batch alone first (most findings need no earlier
  // state), else the whole history; then ddmin on fresh targets.
  Reducer red{open, plan, isolate, finding->kind};
  std::vector<Step> last_batch(history.begin() + long(std::min(last_probe, history.size())), history.end());
  std::vector<Step> minimal;
  if (red.fails(last_batch)) {
    minimal = red.minimize(last_batch);
  } else if (red.fails(history)) {
    minimal = red.minimize(history);
  } else {
    // Timing, state outside the frames, or a target that is gone: keep the
    // last batch as it was sent, unreduced.
    std::printf("the finding does not reproduce on a fresh target (timing, state outside the frames, or the target is gone); "
                "saving the last %zu steps unreduced\n", last_batch.size());
    minimal = last_batch;
  }
  restore();
  fs::path file = save_reproducer(a.out, uri, device, *finding, minimal);
  std::printf("reproducer of %zu step(s) (%d fresh-target runs): %s\n", minimal.size(), red.runs, file.c_str());
  std::printf("replay: mbconform fuzz --replay %s --target '%s' --device %s\n", file.c_str(), uri.c_str(), device.c_str());
  return kExitFailed;
}

}  // namespace

void add_fuzz_command(CLI::App& app, int& exit_code) {
  auto args = std::make_shared<FuzzArgs>();
  auto* cmd = app.add_subcommand("fuzz", "Black-box structure-aware fuzzing of a target; saves minimal reproducers");
  cmd->add_option("--target", args->target, "Target URI: ref:ID, tcp://HOST:PORT, rtu-tcp://HOST:PORT, rtu:///dev/tty..., plugin:PATH.so")
      ->required();
  cmd->add_option("--device", args->device, "Spec id of the device behind the target (ref: targets carry their own)");
  cmd->add_option("--duration", args->duration, "How long to fuzz: 500ms, 20s, 5m, 1h (default 10s)");
  cmd->add_option("--out", args->out, "Directory for reproducers (default fuzz-findings)");
  cmd->add_option("--seed", args->seed, "Random seed (default: from the clock, printed)");
  cmd->add_option("--batch", args->batch, "Frames between two liveness probes (default 50)")->check(CLI::Range(1, 100000));
  cmd->add_option("--replay", args->replay, "Replay a reproducer FILE instead of fuzzing; exit 1 if it still finds");
  cmd->add_flag("--allow-motion", args->allow_motion, "Live targets: allow writes to command and motion registers");
  cmd->add_flag("--allow-eeprom-writes", args->allow_eeprom, "Live targets: allow writes to persistent registers");
  cmd->callback([args, &exit_code] { exit_code = run_fuzz(*args); });
}

}  // namespace mbc::cli
