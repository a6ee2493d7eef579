// One executable form of a check. A conformance case, a step of a property
// counterexample, a fuzz reproducer and a line of a plan are all Steps with an
// Expect, grouped into Cases; one judge (judge.h) decides every reply, one
// exchange (exchange.h) sends every step through a Link with its wait policy
// and counts its bytes, and one text form (text.h, the frame script) writes
// and reads them. cases/ generates Cases from a spec; runner/ orders them,
// runs them again and restores; `mbconform replay` runs a written plan the
// way `run` ran it.
//
//   cases/ properties/ blackbox/      make Steps and Cases
//   runner/                           orders, re-runs, restores
//   check/  (this folder)             Step, Expect, Case; judge; exchange; text
//   session/link.h                    the gate and the journal (a Link)
//   targets/                          ref, tcp, rtu-tcp, rtu, plugin
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "modbus/hex.h"
#include "report/result.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf::check {

// A fact a case relies on, and where it comes from (spec/README.md, "Where
// each fact comes from"). Recorded by the accessors of cases/facts.h only.
struct Reliance {
  std::string fact{};         // "register 0x0BB8 read", "exception_policy.crc_error", "FC 16 max_quantity"
  spec::FactBasis basis{};
};

// What must come back for one step: written when the step is made, from the
// spec or the Modbus standard, never from what a device answered.
struct Expect {
  enum class Kind {
    none,            // nothing checked (setup, a step that only records, an answer the spec leaves open)
    reply,           // the reply PDU is exactly `pdu` (and, when `adu` is set and the target frames RTU, the ADU)
    exception,       // an exception reply with `code` to the request's function code
    silence,         // no reply at all
    normal,          // a well-formed normal reply (MBAP v1.1b3 §6), any values
    registers,       // a well-formed read reply holding exactly `words`
    same,            // a reply equal to the one step `memo` of the same case got
    answered,        // any reply to the request's function code: normal, or an exception (any code); not silence
    any,             // any well-formed reply: normal, or an exception code the standard or the spec knows
    any_or_silence,  // `any`, or no reply (a request the device may drop: fuzzed, malformed)
  } kind = Kind::none;
  Bytes pdu{};
  uint8_t code = 0;
  std::optional<Bytes> adu{};
  std::vector<uint16_t> words{};
  // registers: per word, the bits compared (empty: every bit); a status
  // word names a state by a mask (`registers 0027/006F`: word & 006F == 0027).
  std::vector<uint16_t> masks{};
  int memo = -1;         // `same`: the index of the earlier step (in its case) whose reply this must equal
  std::string text{};      // the expectation in words, for reports ("exception 03 (policy value_out_of_range, §6.2.4)")
  // The facts this expectation was built from (cases/facts.h); a case
  // relies on its steps' facts too.
  std::vector<Reliance> relies{};
  // The source prints two readings: the reply may meet this expectation or
  // any of `either` (each with its `reading` named); the runner records which.
  std::vector<Expect> either{};
  std::string reading{};   // this reading's name ("silence (the text)")
};

struct Step {
  enum class Kind {
    frame,        // a unit and a PDU, framed for whatever target it goes to
    raw,          // bytes that go out exactly as written (`framing` says whose)
    advance,      // the in-process device's virtual clock moves `us`
    power_cycle,  // the in-process device is switched off and on
    wait,         // `us` of real time pass before the next frame
  } kind = Kind::frame;
  // frame: the framing it was written in (how it is printed); raw: the
  // framing its bytes belong to, which the target must have.
  Framing framing = &mbc::kRtu;
  uint8_t unit = 0;                   // frame (0 = broadcast)
  Bytes pdu{};                          // frame
  std::optional<uint16_t> tid{};        // frame printed as MBAP: its transaction id; nullopt prints '*'
  Bytes bytes{};                        // raw: the whole ADU as sent
  std::optional<size_t> gap{};          // raw RTU: an inter-character pause after this many bytes
  uint64_t us = 0;                    // advance, wait
  Expect expect{};
  std::string note{};                   // what the step means ("write 0x0020 = 1000 (FC 06)")
  // frame writes (FC 06/16): when >= 0, the value words are the registers the
  // read at step `words_from` (of the same case) got, filled in when the step
  // is sent (a broadcast that writes back what the target held). Not sent
  // when that read failed.
  int words_from = -1;
  // A setup step (restoring a given state): its failure fails the case with
  // "setup:" but it is not the requirement itself.
  bool setup = false;
  // The device's documentation says this request may go unanswered: a reply
  // it expects is waited for the silence window, not the timeout.
  bool may_go_unanswered = false;
  int line = 0;                       // where it was read (0: not read from a file)
};

// A check: a stable id tied to the clause it checks, the requirement quoted,
// and its steps.
struct Case {
  std::string id{};           // "<device>/<family>/<section-or-register>/<n>"
  std::string family{};       // examples | registers | function-codes | framing | standard | deviations
  std::string clause{};       // "57HS-R §6.2.4", "MBAP v1.1b3 §6.3", "MB-SL v1.02 §2.4.1"
  Level level = Level::must;
  std::string title{};
  std::string requirement{};  // the sentence checked
  std::vector<Step> steps{};
  std::vector<std::string> errata{};
  // The facts the case relies on beyond its steps' expectations
  // (cases/facts.h). settle_level() turns an inferred one into OBSERVED.
  std::vector<Reliance> relies{};
  // Set by settle_level() when an inferred fact moved the case off MUST/SHOULD.
  std::optional<Level> level_if_stated{};
  std::optional<uint16_t> register_address{};  // for the per-register table
  // Registers (holding, address + words) the case writes: they are read
  // before it and written back after it, so cases do not leak state.
  std::vector<std::pair<uint16_t, int>> touches{};
  // Set when the case cannot run on this target (capability, safety): it is
  // reported skip with this reason.
  std::string skip_reason{};
  // Every function is optional (MBAP v1.1b3 §5.1): when set (cases on a
  // server's probed or given map, not on a spec of its own), an exception 01
  // to a step that expected something else means the server does not
  // implement that function, and the case does not apply (skip), rather than
  // fails.
  bool functions_optional = false;
  // Set when the state the case starts from cannot be established through
  // the bus (a printed example whose given input registers or status the
  // bus cannot set): why. Its reply is recorded; one that differs from the
  // printed one is "not comparable" (with this reason), never "differs".
  std::string incomparable{};
  int line = 0;             // where its `case` line was read (0: generated)
};

// Every reliance of a case: its own and its steps' expectations', each fact once.
std::vector<Reliance> all_relies(const Case&);
// "register 0x0BB8 read: inferred (表 14 lists ...; searched 6.1)".
std::string describe(const Reliance&);

// Step builders.
Step frame(Framing framing, uint8_t unit, Bytes pdu, Expect expect = {}, std::string note = "");
Step raw_rtu(Bytes adu, std::optional<size_t> gap = std::nullopt, Expect expect = {}, std::string note = "");
// A split frame (a raw RTU step with a gap) that got a reply is sent again
// once with this pause inside it (at least ten times the first) before the
// reply counts against the device: a receiver that the host held up past the
// first pause may have read both parts as one frame, which says nothing of
// the device; one that joins them again does so for real. The runner and the
// black-box fuzzer both re-check this way.
inline constexpr std::chrono::milliseconds kSplitGapRecheck{250};
Step raw_mbap(Bytes adu, Expect expect = {}, std::string note = "");
Step advance(uint64_t us);
Step power_cycle();

// The bytes a step puts on the wire of a target with `framing` (frame and
// raw steps). A frame's MBAP transaction id is `tid`, or 0 when unknown.
Bytes wire_bytes(const Step& s, Framing framing);

// Whether a step sends a request to unit 0 that is not a read: every drive on
// a serial line acts on it (MB-SL v1.02 §2.1).
bool is_broadcast_write(const Step& st);

// Step `st` with its value words taken from `read_reply` (an FC 03 reply)
// when st.words_from is set; nullopt when the reply holds no usable words.
std::optional<Step> fill_words(const Step& st, const std::optional<Bytes>& read_reply);

}  // namespace mbc::conf::check
