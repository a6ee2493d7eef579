// The judgement of one recorded exchange. Expectations come from the spec
// (through cases/facts.h, so that the level rule of `run` applies) and from
// the standard (modbus/judge.h for the reply's layout); never from what the
// reference devices do.
#include "capture/judge.h"

#include <fmt/core.h>

#include <algorithm>
#include <array>
#include <unordered_map>

#include "cases/facts.h"
#include "modbus/crc16.h"
#include "modbus/function_codes.h"
#include "modbus/judge.h"
#include "modbus/limits.h"
#include "modbus/mbap.h"
#include "modbus/pdu.h"
#include "modbus/rtu.h"

namespace mbc::conf::capture {
namespace {

using spec::PolicyEntry;
using spec::Violation;

struct Pdu {
  uint8_t unit = 0;
  Bytes pdu;
  bool crc_ok = true;
};

Pdu unframe(Carrier c, std::span<const uint8_t> adu) {
  Pdu p;
  if (c == Carrier::mbap) {
    if (adu.size() >= kMbapHeader) {
      p.unit = adu[6];
      p.pdu.assign(adu.begin() + kMbapHeader, adu.end());
    }
  } else if (adu.size() >= 1) {
    p.unit = adu[0];
    auto pdu = adu.size() >= 4 ? kRtu.pdu_bytes(adu) : adu.subspan(1);  // too short for a CRC: all of it
    p.pdu.assign(pdu.begin(), pdu.end());
    p.crc_ok = adu.size() >= 4 && crc_ok(adu);
  }
  return p;
}

// The check a register of this request counts toward: FC 23's registers are
// counted as reads (the read check of each is added beside them).
bool counts_as_write(uint8_t fc) { return is_write_function(fc) && fc != fc::read_write_multiple_registers; }

const char* table_word(spec::Table t) {
  switch (t) {
    case spec::Table::holding: return "holding";
    case spec::Table::input: return "input";
    case spec::Table::coil: return "coils";
    case spec::Table::discrete_input: return "discrete";
  }
  return "holding";
}

std::string policy_text(const PolicyEntry& p, Violation v) {
  std::string where = p.section.empty() ? "" : ", " + p.section;
  switch (p.kind) {
    case PolicyEntry::Kind::exception: return fmt::format("exception {:02X} (policy {}{})", p.code, spec::to_string(v), where);
    case PolicyEntry::Kind::silent: return fmt::format("no reply (policy {}{})", spec::to_string(v), where);
    default: return fmt::format("anything (policy {} not stated)", spec::to_string(v));
  }
}

// A request's classification (cases/facts.h, classify) with its facts
// shared: every verdict on it points at them.
struct Classification {
  facts::Classified c;
  std::shared_ptr<const std::vector<Reliance>> shared;               // c.relies
  std::vector<std::shared_ptr<const std::vector<Reliance>>> breach;  // each c.breaches[i].relies
};

// A request's classification depends on its PDU alone (and the spec): a
// capture repeats its requests (polling), so each distinct one is worked out once.
const Classification& classified(const spec::Spec& s, std::span<const uint8_t> pdu) {
  static std::unordered_map<std::string, std::unique_ptr<Classification>> cache;
  static const spec::Spec* for_spec = nullptr;
  static std::string for_id;
  static size_t for_count = 0;
  if (for_spec != &s || for_id != s.device.id || for_count != s.registers.size() || cache.size() >= 4096) cache.clear();
  for_spec = &s;
  for_id = s.device.id;
  for_count = s.registers.size();
  std::string key(pdu.begin(), pdu.end());
  auto it = cache.find(key);
  if (it != cache.end()) return *it->second;
  auto j = std::make_unique<Classification>();
  j->c = facts::classify(s, pdu);
  j->shared = std::make_shared<const std::vector<Reliance>>(std::move(j->c.relies));
  for (auto& b : j->c.breaches) j->breach.push_back(std::make_shared<const std::vector<Reliance>>(std::move(b.relies)));
  return *cache.emplace(std::move(key), std::move(j)).first->second;
}

Verdict verdict(CheckKey k, bool pass, std::string message, std::shared_ptr<const std::vector<Reliance>> relies = {}) {
  return Verdict{k, pass, std::move(message), std::move(relies)};
}

}  // namespace

std::vector<Verdict> judge_exchange(const spec::Spec& s, const Exchange& x, const JudgeOptions& o) {
  std::vector<Verdict> out;
  Pdu rq = unframe(x.carrier, x.request);
  if (o.unit && rq.unit != *o.unit) return out;
  if (rq.pdu.empty()) return out;  // nothing to judge: a frame with no function code
  uint8_t fc = rq.pdu[0];
  bool rtu = x.carrier == Carrier::rtu;

  // Timing on a serial line (MB-SL v1.02 §2.5.1.1): frames are kept apart by
  // at least 3.5 character times of silence.
  if (x.timed_line) {
    auto t35 = frame_gap(o.baud).count();
    auto gap_check = [&](std::optional<int64_t> gap, const char* which) {
      if (!gap) return;
      bool ok = *gap >= t35;
      out.push_back(verdict({Check::gap_t35}, ok,
                            ok ? "" : fmt::format("{} {} us of silence before the {}, under t3.5 = {} us at {} baud",
                                                  x.conversation, *gap, which, t35, o.baud)));
    };
    gap_check(x.gap_before_request_us, "request");
    if (x.reply) gap_check(x.gap_before_reply_us, "reply");
  }

  if (rtu && !rq.crc_ok) {
    // A corrupted request: the device's answer is its crc_error policy.
    std::vector<Reliance> rel;
    PolicyEntry p = facts::policy(rel, s, Violation::crc_error);
    std::vector<PolicyEntry> readings = p.readings.empty() ? std::vector<PolicyEntry>{p} : p.readings;
    auto shared = std::make_shared<const std::vector<Reliance>>(std::move(rel));
    CheckKey k{Check::policy, 0, Violation::crc_error};
    if (x.reply || x.abandoned) {
      bool ok = std::any_of(readings.begin(), readings.end(), [](const PolicyEntry& e) { return e.kind != PolicyEntry::Kind::silent; });
      out.push_back(verdict(k, ok, ok ? "" : "a reply to a request with a bad CRC; expected " + policy_text(readings[0], Violation::crc_error),
                            shared));
    } else {
      out.push_back(verdict(k, true, "", shared));
    }
    return out;
  }

  // Broadcast (MB-SL v1.02 §2.1): no reply. Only RTU: on Modbus TCP unit 0
  // addresses the server (Implementation Guide V1.0b §4.4.1.2).
  if (rtu && rq.unit == 0) {
    bool ok = !x.reply;
    out.push_back(verdict({Check::broadcast_no_reply}, ok, ok ? "" : "a reply to a broadcast (unit 0): " + to_hex(*x.reply)));
    return out;
  }

  const Classification& jd = classified(s, rq.pdu);
  const facts::Classified& b = jd.c;
  if (!x.reply) {
    if (b.allows_silence()) {
      for (size_t i = 0; i < b.breaches.size(); ++i)
        out.push_back(verdict({Check::policy, 0, b.breaches[i].violation}, true, "", jd.breach[i]));
    } else if (!x.abandoned) {
      // A capture misses packets; its silence is never a failure of the device.
      out.push_back(verdict({Check::unanswered}, false,
                            fmt::format("packet {}: {} FC {:02X} to unit {} got no reply in the capture", x.request_packet,
                                        x.conversation, fc, rq.unit)));
    }
    return out;
  }
  out.push_back(verdict({Check::unanswered}, true, ""));

  Pdu rp = unframe(x.carrier, *x.reply);
  if (rtu) {
    bool ok = rp.crc_ok;
    out.push_back(verdict({Check::reply_crc}, ok, ok ? "" : "reply CRC does not check: " + to_hex(*x.reply)));
    if (!ok) return out;
  }
  {
    // MBAP v1.1b3 §4.1 / MB-SL v1.02 §2.2: the reply carries the unit (slave) it comes from.
    bool ok = rp.unit == rq.unit;
    out.push_back(verdict({Check::unit_echo}, ok, ok ? "" : fmt::format("request to unit {}, reply from unit {}", rq.unit, rp.unit)));
  }
  if (rp.pdu.empty()) {
    out.push_back(verdict({Check::reply_well_formed, fc}, false, "reply without a function code"));
    return out;
  }
  bool exception = (rp.pdu[0] & kExceptionBit) && (rp.pdu[0] & 0x7F) == fc;
  uint8_t code = exception && rp.pdu.size() >= 2 ? rp.pdu[1] : 0;

  if (!b.valid()) {
    // The spec's policy for the breach says the reply; a breach whose policy
    // the spec leaves open is OBSERVED by the level rule.
    bool any_exact = b.open() || (exception && b.allows_exception(code));
    std::string expected;
    for (const auto& a : b.breaches)
      for (const auto& p : a.readings) expected += (expected.empty() ? "" : " or ") + policy_text(p, a.violation);
    std::string got = exception ? fmt::format("exception {:02X} ({})", code, exception_name(code))
                                : "a normal reply: " + describe_pdu(rp.pdu, false);
    for (size_t i = 0; i < b.breaches.size(); ++i)
      out.push_back(verdict({Check::policy, 0, b.breaches[i].violation}, any_exact,
                            any_exact ? "" : fmt::format("packet {}: {} to {}: expected {}, got {}", x.reply_packet,
                                                         describe_pdu(rq.pdu, true), x.conversation, expected, got),
                            jd.breach[i]));
    return out;
  }

  // A request the spec allows: a well-formed normal reply (MBAP v1.1b3 §6).
  if (exception) {
    // 04-06 (device failure, acknowledge, busy) depend on the device's state,
    // not on the request; 01-03 contradict the spec's facts.
    // A value the spec cannot place in or out of range may get its refusal.
    bool contradicts = code >= 1 && code <= 3 && !(b.maybe && b.allows_exception(code));
    out.push_back(verdict({Check::reply_well_formed, fc}, !contradicts,
                          fmt::format("packet {}: exception {:02X} ({}) to {}, which the spec allows", x.reply_packet, code,
                                      exception_name(code), describe_pdu(rq.pdu, true)),
                          jd.shared));
    return out;
  }
  Judged j = judge_reply(rq.pdu, rp.pdu);
  std::vector<std::string> count_problems, other;
  for (auto& p : j.problems) (p.find("byte count") != std::string::npos ? count_problems : other).push_back(p);
  if (j.kind == Judged::Kind::malformed && other.empty() && count_problems.empty()) other.push_back("malformed reply");
  auto joined = [&](const std::vector<std::string>& v) {
    std::string t = fmt::format("packet {}: {}: ", x.reply_packet, describe_pdu(rq.pdu, true));
    for (size_t i = 0; i < v.size(); ++i) t += (i ? "; " : "") + v[i];
    return t;
  };
  out.push_back(verdict({Check::reply_byte_count, fc}, count_problems.empty(), count_problems.empty() ? "" : joined(count_problems), jd.shared));
  out.push_back(verdict({Check::reply_well_formed, fc}, other.empty(), other.empty() ? "" : joined(other), jd.shared));
  bool good = j.ok();
  for (const auto& [table, address] : b.registers) {
    CheckKey k{counts_as_write(fc) ? Check::register_write : Check::register_read, 0, Violation::unsupported_function, table, address};
    out.push_back(verdict(k, good, good ? "" : joined(j.problems)));
    if (fc == fc::read_write_multiple_registers) out.push_back(verdict({Check::register_read, 0, Violation::unsupported_function, table, address}, good, ""));
  }
  if (x.timed_line && x.reply_time_us >= x.request_time_us) {
    out.push_back(verdict({Check::latency}, true,
                          fmt::format("{} us from the request's end to the reply's end", x.reply_time_us - x.request_time_us)));
  }
  return out;
}

Verdict judge_unsolicited(const Frame& f) {
  return verdict({Check::unsolicited}, false,
                 fmt::format("packet {}: {} a reply with no request in the capture: {}", f.packet, f.conversation,
                             to_hex(std::span(f.adu).first(std::min<size_t>(f.adu.size(), 16)))));
}

std::vector<CheckKey> catalogue(const spec::Spec& s) {
  std::vector<CheckKey> keys;
  for (const auto& f : s.profile.function_codes) {
    keys.push_back({Check::reply_well_formed, uint8_t(f.code)});
    keys.push_back({Check::reply_byte_count, uint8_t(f.code)});
  }
  for (auto v : spec::kAllViolations) keys.push_back({Check::policy, 0, v});
  keys.push_back({Check::unit_echo});
  keys.push_back({Check::reply_crc});
  keys.push_back({Check::broadcast_no_reply});
  keys.push_back({Check::gap_t35});
  keys.push_back({Check::gap_t15});
  keys.push_back({Check::latency});
  keys.push_back({Check::unanswered});
  keys.push_back({Check::unsolicited});
  for (const auto& r : s.registers) {
    if (r.access != spec::Access::wo && r.access != spec::Access::command)
      keys.push_back({Check::register_read, 0, Violation::unsupported_function, r.table, r.address});
    if (r.access != spec::Access::ro)
      keys.push_back({Check::register_write, 0, Violation::unsupported_function, r.table, r.address});
  }
  return keys;
}

CaseText case_text(const std::string& device, const CheckKey& k) {
  CaseText t;
  std::string base = device + "/capture/";
  switch (k.check) {
    case Check::reply_well_formed:
      t.id = fmt::format("{}function-codes/fc{:02X}/reply", base, k.function);
      t.clause = "MBAP v1.1b3 §6";
      t.title = fmt::format("FC {:02X} ({}): a request the spec allows gets a well-formed normal reply", k.function, function_name(k.function));
      t.requirement = "The server answers a valid request with the normal response of §6 for its function code.";
      break;
    case Check::reply_byte_count:
      t.id = fmt::format("{}function-codes/fc{:02X}/byte-count", base, k.function);
      t.clause = "MBAP v1.1b3 §6";
      t.title = fmt::format("FC {:02X}: the reply's byte count matches its data and the request", k.function);
      t.requirement = "Byte count: the number of data bytes that follow (2 x quantity for registers, ceil(quantity / 8) for bits).";
      break;
    case Check::policy:
      t.id = fmt::format("{}policy/{}", base, spec::to_string(k.violation));
      t.clause = "MBAP v1.1b3 §7";
      t.title = fmt::format("a request that breaks the spec ({}) gets the answer the exception policy states", spec::to_string(k.violation));
      t.requirement = "The device answers each kind of bad request as its manual's exception policy says (or the standard's exception codes).";
      break;
    case Check::register_read:
    case Check::register_write: {
      bool w = k.check == Check::register_write;
      t.id = fmt::format("{}registers/{}/0x{:04X}/{}", base, table_word(k.table), k.address, w ? "write" : "read");
      t.clause = "MBAP v1.1b3 §6";
      t.title = fmt::format("{} 0x{:04X}: {} answered with a well-formed normal reply", table_word(k.table), k.address, w ? "a write" : "a read");
      t.requirement = "A register the spec maps and allows is read or written with a normal response.";
      t.register_address = k.address;
      break;
    }
    case Check::unit_echo:
      t.id = base + "framing/unit-echo";
      t.clause = "MBAP v1.1b3 §4.1; MB-SL v1.02 §2.2";
      t.title = "the reply carries the unit identifier (slave address) of the request";
      t.requirement = "The server copies the unit identifier of the request into its response; a slave puts its own address in its reply.";
      break;
    case Check::reply_crc:
      t.id = base + "framing/crc";
      t.clause = "MB-SL v1.02 §2.5.1.2";
      t.title = "every RTU reply ends with a CRC that checks";
      t.requirement = "The CRC field is appended to the message as the last field.";
      break;
    case Check::broadcast_no_reply:
      t.id = base + "framing/broadcast";
      t.clause = "MB-SL v1.02 §2.1";
      t.title = "no reply to a broadcast (slave address 0)";
      t.requirement = "Broadcast requests are necessarily writing commands ... No response is returned to broadcast requests by the slaves.";
      break;
    case Check::gap_t35:
      t.id = base + "timing/t3.5";
      t.clause = "MB-SL v1.02 §2.5.1.1";
      t.title = "frames on the line are separated by at least 3.5 character times (serial logs)";
      t.requirement = "Message frames are separated by a silent interval of at least 3.5 character times.";
      t.level = Level::should;  // a log's timestamps carry the sniffer's jitter
      break;
    case Check::gap_t15:
      t.id = base + "timing/t1.5";
      t.clause = "MB-SL v1.02 §2.5.1.1";
      t.title = "no silence over 1.5 character times inside a frame (needs a log with a timestamp per character)";
      t.requirement = "The entire message frame must be transmitted as a continuous stream of characters.";
      t.level = Level::should;
      break;
    case Check::latency:
      t.id = base + "timing/latency";
      t.clause = "MB-SL v1.02 §2.4.1";
      t.title = "reply latency on a timed serial log (recorded: coverage.html plots it)";
      t.requirement = "The response timeout is set by the master; the latencies seen are recorded.";
      t.level = Level::observed;
      break;
    case Check::unanswered:
      t.id = base + "pairing/unanswered";
      t.clause = "MBAP v1.1b3 §4.1";
      t.title = "every request in the capture has its reply (a capture can drop packets: recorded, not failed)";
      t.requirement = "A unicast request gets a response (normal or exception) unless the policy says silence.";
      t.level = Level::observed;
      break;
    case Check::unsolicited:
      t.id = base + "pairing/unsolicited";
      t.clause = "MBAP v1.1b3 §4.1";
      t.title = "no reply without a request (by transaction id on TCP, by order and unit on RTU)";
      t.requirement = "A server answers requests; it sends nothing unasked.";
      t.level = Level::observed;
      break;
  }
  return t;
}

}  // namespace mbc::conf::capture
