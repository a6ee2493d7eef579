// The scenarios of `mbconform client`, each tied to the sentence of the
// standard it checks. Sources, as everywhere in mbconform:
//   MBAP v1.1b3   MODBUS Application Protocol Specification V1.1b3
//   MB-SL v1.02   MODBUS over Serial Line Specification and Implementation Guide V1.02
//   TCP IG v1.0b  MODBUS Messaging on TCP/IP Implementation Guide V1.0b
// A check no clause states is OBSERVED: recorded, never failed.
#include <fmt/core.h>

#include <stdexcept>

#include "client/model.h"
#include "client/scenario.h"
#include "modbus/limits.h"
#include "loader.h"

namespace mbc::client {
namespace {

using nlohmann::json;
using conf::Level;

// ---- the sentences quoted ----
constexpr const char* kPduLimit =
    "MBAP v1.1b3 §4.1: \"MODBUS PDU for serial line communication = 256 - Server address (1 byte) - CRC (2 bytes) = "
    "253 bytes.\"";
constexpr const char* kMbapFields =
    "TCP IG v1.0b §3.1.3: \"Protocol Identifier - ... The MODBUS protocol is identified by the value 0.\" \"Length - "
    "The length field is a byte count of the following fields, including the Unit Identifier and data fields.\"";
constexpr const char* kUnitRouting =
    "MB-SL v1.02 §2.2: \"the master ... addresses ... individual slaves\"; TCP IG v1.0b §3.1.3: \"Unit Identifier - "
    "This field is used for intra-system routing purpose.\" The unit on the wire is the one the caller named.";
constexpr const char* kConfirmation =
    "TCP IG v1.0b §4.2 (Process MODBUS Confirmation): \"If the function code is different from the one used in the "
    "request (=non expected function code), or if the format of the response is incorrect, then an error is signaled "
    "to the user application using a Negative Confirmation.\"";
constexpr const char* kMasterChecks =
    "MB-SL v1.02 §2.4.1: \"When a reply is received, the master checks the reply before starting the data "
    "processing. The checking may result in an error, for example a reply from an unexpected slave or an error in the "
    "received frame.\"";
constexpr const char* kUnexpectedSlave =
    "MB-SL v1.02 §2.4.1: \"In case of a reply received from an unexpected slave, the Response time-out is kept "
    "running.\"";
constexpr const char* kPairing =
    "TCP IG v1.0b §4.2 (Process MODBUS Confirmation): \"If the Transaction Identifier does not refer to any MODBUS "
    "pending transaction, the response must be discarded.\"";
constexpr const char* kException =
    "MBAP v1.1b3 §7: \"In the exception response, the server ... returns an exception code ... [that] indicates the "
    "reason for the exception\"; TCP IG v1.0b §4.2: \"If the function code is a MODBUS exception code (Function code + "
    "80H), the MODBUS exception response is given to the user application as a Negative Confirmation.\"";
constexpr const char* kCrc =
    "MB-SL v1.02 §2.5.1.2: \"The receiving device recalculates a CRC during receipt of the message, and compares the "
    "calculated value to the actual value it received in the CRC field. If the two values are not equal, an error "
    "results.\"";
constexpr const char* kIncomplete =
    "MB-SL v1.02 §2.5.1.1: \"If a silent interval of more than 1.5 character times occurs between two characters, the "
    "message frame is declared incomplete and should be discarded by the receiver.\"";
constexpr const char* kLength =
    "TCP IG v1.0b §3.1.3: \"Length - The length field is a byte count of the following fields, including the Unit "
    "Identifier and data fields.\" A reply is whole when that many bytes arrived, however TCP segments it.";
constexpr const char* kTimeout =
    "MB-SL v1.02 §2.4.1: \"the master ... starts a 'response time-out' ... If no reply is received within the "
    "time-out the master ... returns to the 'idle' state\", ready for the next request.";
constexpr const char* kBroadcast =
    "MB-SL v1.02 §2.1: \"Broadcast mode: ... No response is returned to broadcast requests sent by the master.\"";

// ---- the requests ----
json op(const char* name, json args) {
  args["op"] = name;
  if (!args.contains("unit")) args["unit"] = model::kUnit;
  return args;
}

struct OpCase {
  const char* clause;  // the function code's clause
  const char* layout;  // its request layout, quoted
  json request;
};

std::vector<OpCase> op_cases() {
  return {
      {"MBAP v1.1b3 §6.1", "\"Quantity of coils 2 Bytes 1 to 2000 (0x7D0)\"",
       op("read_coils", {{"address", 3}, {"count", 10}})},
      {"MBAP v1.1b3 §6.2", "\"Quantity of Inputs 2 Bytes 1 to 2000 (0x7D0)\"",
       op("read_discrete_inputs", {{"address", 3}, {"count", 10}})},
      {"MBAP v1.1b3 §6.3", "\"Quantity of Registers 2 Bytes 1 to 125 (0x7D)\"",
       op("read_holding_registers", {{"address", 0x10}, {"count", 5}})},
      {"MBAP v1.1b3 §6.4", "\"Quantity of Input Registers 2 Bytes 0x0001 to 0x007D\"",
       op("read_input_registers", {{"address", 0x10}, {"count", 5}})},
      {"MBAP v1.1b3 §6.5", "\"Output Value 2 Bytes 0x0000 or 0xFF00\"",
       op("write_single_coil", {{"address", 7}, {"value", true}})},
      {"MBAP v1.1b3 §6.6", "\"Register Value 2 Bytes 0x0000 to 0xFFFF\"",
       op("write_single_register", {{"address", 0x20}, {"value", 0x1234}})},
      {"MBAP v1.1b3 §6.11", "\"Quantity of Outputs 2 Bytes 0x0001 to 0x07B0\", \"Byte Count 1 Byte N*\"",
       op("write_multiple_coils",
          {{"address", 0x13}, {"values", {true, false, true, true, false, false, true, true, true, false}}})},
      {"MBAP v1.1b3 §6.12", "\"Quantity of Registers 2 Bytes 0x0001 to 0x007B\", \"Byte Count 1 Byte 2 x N*\"",
       op("write_multiple_registers", {{"address", 0x30}, {"values", {0x000A, 0x0102, 0xFFFF}}})},
      {"MBAP v1.1b3 §6.16", "\"Reference Address 2 Bytes\", \"And_Mask 2 Bytes\", \"Or_Mask 2 Bytes\"",
       op("mask_write_register", {{"address", 4}, {"and_mask", 0x00F2}, {"or_mask", 0x0025}})},
      {"MBAP v1.1b3 §6.17",
       "\"Quantity to Read 2 Bytes 0x0001 to 0x007D\", \"Quantity to Write 2 Bytes 0x0001 to 0x0079\", \"Write Byte "
       "Count 1 Byte 2 x N*\"",
       op("read_write_multiple_registers",
          {{"read_address", 3}, {"read_count", 6}, {"write_address", 0x0E}, {"values", {0x00FF, 0x00FE, 0x00FD}}})},
      {"MBAP v1.1b3 §6.21", "\"MEI Type 1 Byte 0x0E\", \"Read Device ID code 1 Byte 01 / 02 / 03 / 04\", \"Object Id\"",
       op("read_device_identification", {{"object_id", 0}})},
  };
}

Passing correct_answer(const json& request) {
  Passing p;
  p.kinds = {"ok"};
  json v = model::expected_values(request);
  if (!v.is_null()) p.values = v;
  return p;
}

ScenarioStep step(json request, Fault fault, Passing pass) {
  ScenarioStep s;
  s.request = std::move(request);
  s.fault = fault;
  s.pass = std::move(pass);
  return s;
}

Passing kinds(std::set<std::string> k) {
  Passing p;
  p.kinds = std::move(k);
  return p;
}

// The request of most reply scenarios: five holding registers at 0x0010.
json read5() { return op("read_holding_registers", {{"address", 0x10}, {"count", 5}}); }

Passing right_or_error(const json& request) {
  Passing p = correct_answer(request);
  p.kinds.insert({"invalid_reply", "timeout"});
  return p;
}

void request_scenarios(std::vector<Scenario>& out, const Framing& wire) {
  for (auto& c : op_cases()) {
    std::string name = c.request.at("op").get<std::string>();
    Scenario s;
    s.id = "client/request/" + name;
    s.family = "client-requests";
    s.clause = std::string(c.clause) + (&wire == &kTcp ? "; TCP IG v1.0b §3.1.3" : "; MB-SL v1.02 §2.5.1");
    s.level = Level::must;
    s.title = fmt::format("{} (FC {:02X}): the request is well formed, for the unit asked, and the reply's values reach the caller",
                          name, model::function_of(name));
    s.requirement = fmt::format("{} {}. {} {}", c.clause, c.layout, &wire == &kTcp ? kMbapFields : kCrc, kUnitRouting);
    s.op = name;
    s.steps.push_back(step(c.request, Fault::none, correct_answer(c.request)));
    out.push_back(std::move(s));
  }
}

// Quantities over the standard's limits: the library should refuse them;
// two of them make a PDU over 253 bytes, which nothing may send.
void limit_scenarios(std::vector<Scenario>& out, const Limits& lim) {
  struct Limit {
    const char* name;
    const char* clause;
    Level level;
    std::string why;
    json request;
  };
  auto over = [](int max) { return max + 1; };
  std::vector<uint16_t> wr(size_t(over(lim.write_multiple_registers)), 0x0101), rw(size_t(over(lim.rw_write)), 0x0202);
  std::vector<bool> coils(size_t(over(lim.write_multiple_coils)), true);
  // A PDU over 253 bytes is a MUST (§4.1); a quantity over its field's range
  // with a PDU that fits, a SHOULD.
  auto level_for = [](const json& r) { return model::expected_request(r).size() > kMaxPdu ? Level::must : Level::should; };
  std::vector<Limit> limits = {
      {"read_coils", "MBAP v1.1b3 §6.1", Level::should,
       fmt::format("\"Quantity of coils 2 Bytes 1 to 2000 (0x7D0)\": {} asked", over(lim.read_coils)),
       op("read_coils", {{"address", 0}, {"count", over(lim.read_coils)}})},
      {"read_holding_registers", "MBAP v1.1b3 §6.3", Level::should,
       fmt::format("\"Quantity of Registers 2 Bytes 1 to 125 (0x7D)\": {} asked", over(lim.read_holding_registers)),
       op("read_holding_registers", {{"address", 0}, {"count", over(lim.read_holding_registers)}})},
      {"write_multiple_coils", "MBAP v1.1b3 §6.11", Level::should,
       fmt::format("\"Quantity of Outputs 2 Bytes 0x0001 to 0x07B0\": {} asked", coils.size()),
       op("write_multiple_coils", {{"address", 0}, {"values", coils}})},
      {"write_multiple_registers", "MBAP v1.1b3 §4.1, §6.12", Level::should,
       fmt::format("\"Quantity of Registers 2 Bytes 0x0001 to 0x007B\": {} asked", wr.size()),
       op("write_multiple_registers", {{"address", 0}, {"values", wr}})},
      {"read_write_multiple_registers", "MBAP v1.1b3 §4.1, §6.17", Level::should,
       fmt::format("\"Quantity to Write 2 Bytes 0x0001 to 0x0079\": {} asked", rw.size()),
       op("read_write_multiple_registers", {{"read_address", 0}, {"read_count", 1}, {"write_address", 0}, {"values", rw}})},
  };
  for (auto& l : limits) {
    l.level = level_for(l.request);
    size_t pdu = model::expected_request(l.request).size();
    if (l.level == Level::must) l.why += fmt::format(", a {}-byte PDU", pdu);
  }
  for (const auto& l : limits) {
    Scenario s;
    s.id = std::string("client/request/over-limit/") + l.name;
    s.family = "client-requests";
    s.clause = l.clause;
    s.level = l.level;
    s.title = fmt::format("{} over its quantity limit: the library refuses it rather than send it", l.name);
    s.requirement = fmt::format("{} {}{}", l.clause, l.why, l.level == Level::must ? std::string(". ") + kPduLimit : "");
    s.op = l.name;
    ScenarioStep st = step(l.request, Fault::exception, kinds({"refused"}));
    st.code = 0x03;  // what a standard server answers if it is sent after all
    st.must_not_send = true;
    s.steps.push_back(std::move(st));
    out.push_back(std::move(s));
  }
}

Scenario reply_scenario(const char* id, const char* clause, Level level, std::string title, std::string requirement) {
  Scenario s;
  s.id = std::string("client/reply/") + id;
  s.family = "client-replies";
  s.clause = clause;
  s.level = level;
  s.title = std::move(title);
  s.requirement = std::move(requirement);
  s.op = "read_holding_registers";
  return s;
}

void reply_scenarios(std::vector<Scenario>& out, const Framing& wire) {
  bool tcp = &wire == &kTcp;
  json r = read5();
  Passing right = correct_answer(r);
  Passing error = kinds({"invalid_reply", "timeout"});
  const char* format_clause = tcp ? "TCP IG v1.0b §4.2" : "MB-SL v1.02 §2.4.1";
  const char* format_text = tcp ? kConfirmation : kMasterChecks;
  {
    auto s = reply_scenario("exception", "MBAP v1.1b3 §7", Level::must,
                            "an exception reply (02, illegal data address): the code reaches the caller", kException);
    Passing p;
    p.kinds = {"exception"};
    p.code = 0x02;
    ScenarioStep st = step(r, Fault::exception, p);
    st.code = 0x02;
    s.steps.push_back(st);
    out.push_back(s);
  }
  if (tcp) {
    auto s = reply_scenario("wrong-transaction-id", "TCP IG v1.0b §4.2", Level::must,
                            "a reply with another transaction id (other values), then the right one: the other values "
                            "never reach the caller",
                            kPairing);
    s.steps.push_back(step(r, Fault::wrong_transaction, right_or_error(r)));
    out.push_back(s);
  }
  {
    // On a serial line the standard says what the master does; on TCP it
    // does not say that a client checks the unit id of a reply.
    auto s = reply_scenario("wrong-unit", tcp ? "TCP IG v1.0b §3.1.3" : "MB-SL v1.02 §2.4.1",
                            tcp ? Level::observed : Level::must,
                            "a reply from another unit (other values), then the right one: the other values never "
                            "reach the caller",
                            tcp ? std::string("TCP IG v1.0b §3.1.3: \"The MODBUS server copies in the response the Unit "
                                              "Identifier of the request.\" (no clause says what a client does with "
                                              "another one: OBSERVED)")
                                : std::string(kUnexpectedSlave));
    s.steps.push_back(step(r, Fault::wrong_unit, right_or_error(r)));
    out.push_back(s);
  }
  {
    auto s = reply_scenario("wrong-function-code", format_clause, Level::must,
                            "an FC 04 reply to an FC 03 request: an error, not values", format_text);
    s.steps.push_back(step(r, Fault::wrong_function, error));
    out.push_back(s);
  }
  if (!tcp) {
    auto s = reply_scenario("bad-crc", "MB-SL v1.02 §2.5.1.2", Level::must, "the right reply with a wrong CRC: an error, not values", kCrc);
    s.steps.push_back(step(r, Fault::bad_crc, error));
    out.push_back(s);
  }
  // Malformed replies: each passes only as an error reported to the caller.
  struct Malformed {
    const char* id;
    Fault fault;
    const char* title;
  };
  const Malformed malformed[] = {
      {"truncated", Fault::truncated, "the first half of the reply, then nothing: an error, not values"},
      {"trailing-bytes", Fault::trailing_bytes, "two bytes more than the byte count says (inside the frame): an error, not values"},
      {"byte-count-short", Fault::byte_count, "four registers for the five asked (byte count 8): an error, not values"},
      {"too-many-registers", Fault::too_many, "six registers for the five asked (byte count 12): an error, not values"},
  };
  for (const auto& m : malformed) {
    // A truncated RTU frame is an incomplete frame (MB-SL §2.5.1.1); the rest are wrong formats.
    bool incomplete = !tcp && m.fault == Fault::truncated;
    auto s = reply_scenario(m.id, incomplete ? "MB-SL v1.02 §2.5.1.1" : format_clause, Level::must, m.title,
                            incomplete ? kIncomplete : format_text);
    s.steps.push_back(step(r, m.fault, error));
    out.push_back(s);
  }
  if (tcp) {
    auto s = reply_scenario("split-segments", "TCP IG v1.0b §3.1.3", Level::must,
                            "the right reply in three TCP segments 30 ms apart: the values reach the caller", kLength);
    s.steps.push_back(step(r, Fault::split, right));
    out.push_back(s);
  }
  {
    // TCP: the late reply's transaction is no longer pending. A serial line
    // has no transaction id, and no clause says what a master does with a
    // frame that arrives after its time-out: OBSERVED there.
    auto s = reply_scenario("late-reply", tcp ? "TCP IG v1.0b §4.2" : "MB-SL v1.02 §2.4.1", tcp ? Level::must : Level::observed,
                            "a reply (other values) 200 ms after the master's time-out: a time-out, and it is not "
                            "taken as the answer to the next request",
                            tcp ? kPairing : "MB-SL v1.02 §2.4.1 states the response time-out, not what becomes of a "
                                             "reply after it: OBSERVED");
    s.steps.push_back(step(r, Fault::late, kinds({"timeout"})));
    s.steps.push_back(step(r, Fault::none, right_or_error(r)));
    out.push_back(s);
  }
  {
    auto s = reply_scenario("no-reply", tcp ? "TCP IG v1.0b §4.2" : "MB-SL v1.02 §2.4.1", Level::must,
                            "no reply at all: a time-out, and the next request works", kTimeout);
    s.steps.push_back(step(r, Fault::silence, kinds({"timeout"})));
    s.steps.push_back(step(r, Fault::none, right));
    out.push_back(s);
  }
  if (!tcp) {
    auto s = reply_scenario("garbage-before-reply", "MB-SL v1.02 §2.5.1.1", Level::must,
                            "three bytes of line noise, a frame gap, then the right reply: never other values",
                            std::string(kIncomplete) + " " + kCrc);
    s.steps.push_back(step(r, Fault::garbage_first, right_or_error(r)));
    out.push_back(s);
    auto b = reply_scenario("broadcast", "MB-SL v1.02 §2.1", Level::should,
                            "a broadcast write (unit 0): no reply comes, and the library does not report that as an error",
                            kBroadcast);
    b.op = "write_single_register";
    json w = op("write_single_register", {{"address", 0x20}, {"value", 0x0042}, {"unit", 0}});
    b.steps.push_back(step(w, Fault::silence, kinds({"ok"})));
    out.push_back(b);
    // MB-SL v1.02 §2.4.1 names no figure for the turnaround delay: the wait
    // is recorded (the runner adds it), and t3.5 is client/timing/t3.5's.
    Scenario t;
    t.id = "client/timing/broadcast-turnaround";
    t.family = "client-timing";
    t.clause = "MB-SL v1.02 §2.4.1";
    t.level = Level::observed;
    t.title = "after a broadcast, the master waits its turnaround delay before the next request";
    t.requirement =
        "MB-SL v1.02 §2.4.1: after a broadcast request the master waits for a \"turnaround delay\", long enough for "
        "any slave to process the broadcast before it can receive a new request (no figure: OBSERVED, the wait recorded)";
    t.op = "write_single_register";
    t.steps.push_back(step(w, Fault::silence, kinds({"ok"})));
    t.steps.push_back(step(r, Fault::none, right));
    out.push_back(t);
  }
}

}  // namespace

const char* to_string(Fault f) {
  switch (f) {
    case Fault::none: return "correct reply";
    case Fault::exception: return "exception reply";
    case Fault::wrong_transaction: return "wrong transaction id, then the right reply";
    case Fault::wrong_unit: return "wrong unit id, then the right reply";
    case Fault::wrong_function: return "FC 04 reply";
    case Fault::bad_crc: return "bad CRC";
    case Fault::truncated: return "first half of the reply";
    case Fault::trailing_bytes: return "two trailing bytes";
    case Fault::byte_count: return "one register short";
    case Fault::too_many: return "one register more";
    case Fault::split: return "three segments, 30 ms apart";
    case Fault::late: return "reply 200 ms after the time-out";
    case Fault::silence: return "no reply";
    case Fault::garbage_first: return "line noise, gap, reply";
  }
  return "?";
}

bool Passing::accepts(const Answer& a) const {
  if (!kinds.count(a.kind)) return false;
  if (a.kind == "ok" && values && a.values != *values) return false;
  if (a.kind == "exception" && a.code != code) return false;
  return true;
}

std::string Passing::text() const {
  std::string t;
  for (const auto& k : kinds) {
    if (!t.empty()) t += " | ";
    t += k;
    if (k == "ok" && values) t += " " + values->dump();
    if (k == "exception") t += fmt::format(" {:02X}", code);
  }
  return t;
}

Limits standard_limits() {
  spec::Spec s = spec::load_spec_by_id("modbus-standard");
  auto find = [&](int code) -> const spec::FunctionCode& {
    for (const auto& f : s.profile.function_codes)
      if (f.code == code) return f;
    throw std::runtime_error(fmt::format("modbus-standard.yaml: no function code {}", code));
  };
  auto need = [](const std::optional<int>& v, int code) {
    if (!v) throw std::runtime_error(fmt::format("modbus-standard.yaml: function code {} states no quantity limit", code));
    return *v;
  };
  Limits l;
  l.read_coils = need(find(1).max_quantity, 1);
  l.read_holding_registers = need(find(3).max_quantity, 3);
  l.write_multiple_coils = need(find(15).max_quantity, 15);
  l.write_multiple_registers = need(find(16).max_quantity, 16);
  l.rw_write = need(find(23).max_write_quantity, 23);
  return l;
}

std::vector<Scenario> scenarios(const Framing& wire, bool timing_on_pty, const Limits& limits) {
  std::vector<Scenario> out;
  request_scenarios(out, wire);
  limit_scenarios(out, limits);
  reply_scenarios(out, wire);
  return out;
}

std::vector<Scenario> run_wide_checks(const Framing& wire, bool serial_line, bool timing_on_pty) {
  std::vector<Scenario> out;
  if (&wire == &kTcp) {
    Scenario s;
    s.id = "client/request/transaction-ids";
    s.family = "client-requests";
    s.clause = "TCP IG v1.0b §3.1.3";
    s.level = Level::observed;
    s.title = "each request of a connection carries a transaction id the one before it did not";
    s.requirement =
        "TCP IG v1.0b §3.1.3: \"Transaction Identifier - It is used for transaction pairing\"; the guide asks for "
        "uniqueness among pending transactions only, so a reused id is recorded, never failed (OBSERVED)";
    out.push_back(s);
    return out;
  }
  if (!serial_line) return out;  // RTU over TCP: TCP carries no character timing
  Level timing = timing_on_pty ? Level::observed : Level::must;
  const char* why = timing_on_pty ? " (a pty has no character timing: OBSERVED)" : "";
  Scenario t15;
  t15.id = "client/timing/t1.5";
  t15.family = "client-timing";
  t15.clause = "MB-SL v1.02 §2.5.1.1";
  t15.level = timing;
  t15.title = "no silence over 1.5 character times inside a request frame";
  t15.requirement = std::string(kIncomplete) + why;
  out.push_back(t15);
  Scenario t35;
  t35.id = "client/timing/t3.5";
  t35.family = "client-timing";
  t35.clause = "MB-SL v1.02 §2.5.1.1";
  t35.level = timing;
  t35.title = "at least 3.5 character times of silence before each request frame";
  t35.requirement = std::string("MB-SL v1.02 §2.5.1.1: \"message frames are separated by a silent interval of at least "
                                "3.5 character times\"") + why;
  out.push_back(t35);
  return out;
}

}  // namespace mbc::client
