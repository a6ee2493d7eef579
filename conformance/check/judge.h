// The one judge: whether a reply meets a step's expectation. Cases, plans,
// replays, property counterexamples and the black-box fuzzer are all judged
// here, so a plan replays the way the run judged it.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "check/check.h"

namespace mbc::conf::check {

// How an exchange departed from its expectation: its kind (one enum from
// here to every report: report/result.h's MismatchKind), why in full, and
// what the device did against what was due in words free of addresses and
// values (report/result.h's Cause groups failures by them).
struct Mismatch {
  using Kind = MismatchKind;
  Kind kind;
  std::string why;
  std::string due{};  // "exception 01", "silence", "a normal reply", "the stated value"
  std::string did{};  // "exception 02", "a reply", "another value"
};

// What the judge needs beyond the step and the reply.
struct JudgeContext {
  uint8_t unit = 1;                  // the unit the target is addressed as
  Framing framing = &mbc::kRtu;    // the target's framing (an exact ADU is checked on RTU only)
  const spec::Spec* spec = nullptr;  // adds the exception codes the device documents
  // The replies (PDUs) of the earlier steps of the same case (`same`).
  std::span<const std::optional<Bytes>> earlier;
  // The target's line may hold other units (a live RTU line; TargetInfo::live):
  // see reply_is_targets. In process (ref:, a plugin) the target is alone.
  bool shared_line = false;
};

// Empty when `reply` to step `s` meets s.expect (or one of its `either`
// readings: use judge_reading to learn which).
std::optional<Mismatch> judge(const Step& s, const Reply& reply, const JudgeContext& ctx);
// The same for one expectation, ignoring its `either`.
std::optional<Mismatch> judge_expect(const Expect& e, const Step& s, const Reply& reply, const JudgeContext& ctx);
// Which reading the reply met ("" when none): the expectation's own
// `reading` (or its text) or one of its `either`.
std::string judge_reading(const Step& s, const Reply& reply, const JudgeContext& ctx);

// The request PDU a step carries, as the addressed receiver sees it: a
// frame's PDU; for raw RTU bytes, the part (of the two a gap makes) that is
// a valid frame for `unit`, if any; for raw MBAP bytes, the PDU after a
// whole, well-formed header (protocol 0, length right, `unit`), if any.
std::optional<Bytes> request_pdu(const Step& s, uint8_t unit);

bool exception_code_known(const spec::Spec* spec, uint8_t code);

// Whether a reply to a frame addressed to unit `to` (0: broadcast) is the
// target's. On a multi-drop RTU line (ctx.shared_line; MB-SL v1.02 §2.2) a
// frame for another unit is answered by that unit: a reply is the target's
// only when its CRC checks and it carries the target's address (ctx.unit);
// one that cannot be told apart is not held against the target. A reply to
// a broadcast is the target's unless it names another drive (a good CRC and
// an address other than 0 and the target's). A frame to the target's own
// unit, every reply of a target alone on its line, and every Modbus TCP
// reply are the target's.
bool reply_is_targets(uint8_t to, std::span<const uint8_t> reply, const JudgeContext& ctx);

// The expectation in words ("exception 03", "exactly 03 02 00 01", ...).
std::string describe(const Expect&);
// What an expectation makes due, free of addresses and values ("exception
// 03", "the stated reply", "silence"): the `due` of a Mismatch.
std::string due_words(const Expect&);

// The reply an expectation fixes, framed as it comes back from a target of
// `framing` (RTU for frame steps on RTU targets; else the PDU), for reports;
// nullopt when the expectation fixes no bytes.
std::optional<Bytes> expected_bytes(const Step& s, const JudgeContext& ctx);

}  // namespace mbc::conf::check
