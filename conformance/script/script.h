// The frame script: one text format for a sequence of frames with their
// expectations (README.md beside this file has the grammar). Case plans
// (`run --plan`), property counterexamples and regressions, and fuzz
// reproducers are all written in it; `mbconform replay FILE --target URI`
// replays any of them on any target.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "modbus/hex.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf::script {

// The first line of every script; a later format gets a new number.
inline constexpr const char* kHeader = "mbconform-script 1";

// What must come back for one frame: written into the file when it is
// created, from the spec or the standard, never from what a device answered.
struct Expect {
  enum class Kind {
    none,       // nothing checked (setup; a frame whose answer the spec leaves open)
    reply,      // a well-formed reply whose PDU is exactly `pdu`
    exception,  // an exception reply with `code` to the request's function code
    silence,    // no reply at all
    normal,     // a well-formed normal reply, any values
    any,        // any well-formed reply: normal, or an exception code the standard or the spec knows
    any_or_silence,  // `any`, or no reply (a request the device may drop: fuzzed, malformed)
  } kind = Kind::none;
  Bytes pdu;
  uint8_t code = 0;
};

struct Step {
  enum class Kind {
    frame,        // a unit and a PDU, framed for whatever target replays it
    raw,          // bytes that go out exactly as written (framing says which)
    advance,      // the in-process device's virtual clock moves `us`
    power_cycle,  // the in-process device is switched off and on
    wait,         // `us` of real time pass before the next frame
  } kind = Kind::frame;
  // frame: the framing it was sent in (how it is printed); raw: the framing
  // its bytes belong to, which the replaying target must have.
  Framing framing = Framing::rtu;
  uint8_t unit = 0;                   // frame (0 = broadcast)
  Bytes pdu;                          // frame
  std::optional<uint16_t> tid;        // frame printed as MBAP: its transaction id; nullopt prints '*'
  Bytes bytes;                        // raw: the whole ADU as sent
  std::optional<size_t> gap;          // raw RTU: an inter-character pause after this many bytes
  uint64_t us = 0;                    // advance, wait
  Expect expect;
  std::string note;                   // what the step means ("write 0x0020 = 1000")
  int line = 0;                       // where it was read (0: not read from a file)
};

struct Script {
  std::string device;                 // spec id (`device ID`), optional
  std::string fault;                  // `fault NAME`: the broken reference device it was found with
  std::string comment;                // the leading comment lines, without '#'
  std::vector<Step> steps;
};

// A script that cannot be read: "file:line:col: error: rule: what".
struct ParseError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

Script parse(const std::string& text, const std::string& file = "<script>");
Script parse_file(const std::string& path);  // also throws ParseError when unreadable

// The line of one step ("rtu 01 03 00 20 00 01 85 C0  -> normal   # read 0x0020").
std::string line(const Step& s);
std::string expect_text(const Expect& e);
// The whole script, header first.
std::string format(const Script& s);

// Step builders.
Step frame(Framing framing, uint8_t unit, Bytes pdu, Expect expect = {}, std::string note = "");
Step raw_rtu(Bytes adu, std::optional<size_t> gap = std::nullopt, Expect expect = {}, std::string note = "");
Step advance(uint64_t us);
Step power_cycle();

// The bytes a step puts on the wire of a target with `framing` (frame and
// raw steps). A frame's MBAP transaction id is `tid`, or 0 when unknown.
Bytes wire_bytes(const Step& s, Framing framing);
// The request PDU a step carries, as the addressed receiver sees it: a
// frame's PDU; for raw RTU bytes, the part (of the two a gap makes) that is
// a valid frame for `unit`, if any; for raw MBAP bytes, what follows the header.
std::optional<Bytes> request_pdu(const Step& s, uint8_t unit);

// How an exchange departed from its expectation.
struct Mismatch {
  enum class Kind {
    answered,          // a reply where silence was expected
    malformed_framing, // a reply whose framing is wrong (CRC, unit, transaction)
    silent,            // silence where a reply was expected
    malformed_reply,   // the reply PDU breaks MBAP v1.1b3 for the request
    unknown_exception, // an exception code neither the standard nor the spec knows
    refused,           // an exception where a normal reply was expected
    different,         // a well-formed reply other than the expected one
  } kind;
  std::string why;
};
// Judges `reply` to step `s` against s.expect (the standard; `spec`, when
// given, adds the exception codes the device documents).
std::optional<Mismatch> check(const Step& s, uint8_t unit, const Reply& reply, const spec::Spec* spec);
bool exception_code_known(const spec::Spec* spec, uint8_t code);

// What replaying a script on a target came to.
struct ReplayResult {
  enum class Outcome { met, failed, cannot_run } outcome = Outcome::met;  // exit 0, 1, 2
  int line = 0;           // the step that failed or cannot run
  std::string message;
  std::vector<Reply> replies;
};
// Whether every step can run on a target of `info` (raw bytes in its
// framing, advance/power-cycle only in process); the first that cannot, with why.
std::optional<std::pair<int, std::string>> unsupported(const Script& s, const TargetInfo& info);
// Sends every step and checks every expectation; stops at the first miss.
ReplayResult replay(Target& target, const Script& s, const spec::Spec* spec);

}  // namespace mbc::conf::script
