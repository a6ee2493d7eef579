// Judging one recorded exchange against the spec and the standard. Every
// verdict check-capture gives comes from judge_exchange(): when the one judge
// of conformance/check/ lands, this is the function that switches to it.
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "capture/frames.h"
#include "cases/case.h"
#include "spec.h"

namespace mbc::conf::capture {

// A request and what came back to it, as the capture holds them.
struct Exchange {
  uint32_t stream = 0;
  std::string conversation;
  Carrier carrier = Carrier::mbap;
  uint64_t request_packet = 0, reply_packet = 0;
  uint64_t request_time_us = 0, reply_time_us = 0;
  Bytes request;               // the ADU as captured
  std::optional<Bytes> reply;  // nullopt: no reply in the capture
  bool timed_line = false;     // a serial log: times are the frames' ends on the line
  // Timed lines: the silence before the request and before the reply, from
  // the end of the frame before (none for the log's first frame).
  std::optional<int64_t> gap_before_request_us, gap_before_reply_us;
  // The conversation's reader had to give the request up (too many waiting,
  // the conversation evicted): no verdict from its silence.
  bool abandoned = false;
};

// What a verdict is about: becomes the case id
// "<device>/capture/<family>/<...>" (case_id()).
enum class Check : uint8_t {
  reply_well_formed,   // function-codes/fcXX/reply
  reply_byte_count,    // function-codes/fcXX/byte-count
  policy,              // policy/<violation>
  register_read,       // registers/<table>/0xADDR/read
  register_write,      // registers/<table>/0xADDR/write
  unit_echo,           // framing/unit-echo
  reply_crc,           // framing/crc
  broadcast_no_reply,  // framing/broadcast
  gap_t35,             // timing/t3.5
  gap_t15,             // timing/t1.5
  latency,             // timing/latency
  unanswered,          // pairing/unanswered
  unsolicited,         // pairing/unsolicited
};

struct CheckKey {
  Check check = Check::reply_well_formed;
  uint8_t function = 0;
  spec::Violation violation = spec::Violation::unsupported_function;
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  uint64_t packed() const {
    return uint64_t(check) << 48 | uint64_t(function) << 40 | uint64_t(violation) << 32 | uint64_t(table) << 24 |
           uint64_t(address);
  }
};

struct Verdict {
  CheckKey key;
  bool pass = true;
  std::string message;             // why it failed, what was observed
  // The spec's facts the verdict rests on (cases/facts.h); shared, since the
  // same request's facts are worked out once and reused (judge.cpp).
  std::shared_ptr<const std::vector<Reliance>> relies;
};

struct JudgeOptions {
  std::optional<int> unit;  // only this unit is judged (--unit)
  int baud = 19200;         // serial logs: the line rate for t1.5 and t3.5
};

// Every verdict on `x` (empty when its unit is not judged).
std::vector<Verdict> judge_exchange(const spec::Spec&, const Exchange& x, const JudgeOptions&);
// A reply the capture holds with no request to pair it with.
Verdict judge_unsolicited(const Frame& reply);

// The case a key stands for: id (under `device`), clause, title, the
// requirement, and the register it is about, if any.
struct CaseText {
  std::string id, clause, title, requirement;
  std::optional<uint16_t> register_address;
  Level level = Level::must;
};
CaseText case_text(const std::string& device, const CheckKey&);

// Every case the spec makes checkable from a capture, exercised or not.
std::vector<CheckKey> catalogue(const spec::Spec&);

}  // namespace mbc::conf::capture
