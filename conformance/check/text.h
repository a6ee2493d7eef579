// The one text form of checks: the frame script (README.md beside this file
// has the grammar). Case plans (`run --plan`), property counterexamples and
// regressions, and fuzz reproducers are all written in it; `mbconform
// replay FILE --target URI` runs any of them on any target. Version 2 groups
// steps into cases (`case ID LEVEL CLAUSE`), so that a plan replays the way
// `run` judged it; a script of version 1 reads as steps without a case.
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

#include "check/check.h"

namespace mbc::conf::check {

// The first line of every script written; a later format gets a new number.
inline constexpr const char* kHeader = "mbconform-script 2";
inline constexpr const char* kHeaderV1 = "mbconform-script 1";  // read too: v1 is v2 without cases

struct Script {
  std::string device;                 // spec id (`device ID`), optional
  std::string fault;                  // `fault NAME`: the broken reference device it was found with
  std::string comment;                // the leading comment lines, without '#'
  std::vector<Step> steps;            // steps before any `case` line (a reproducer, a regression)
  std::vector<Case> cases;            // `case` blocks (a plan)
};

// A script that cannot be read: "file:line:col: error: rule: what".
struct ParseError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

Script parse(const std::string& text, const std::string& file = "<script>");
Script parse_file(const std::string& path);  // also throws ParseError when unreadable

// The line of one step ("rtu 01 03 00 20 00 01 85 C0  -> normal   # read 0x0020").
// `framing`: how a frame step is printed (nullopt: its own `framing`).
std::string line(const Step& s, std::optional<Framing> framing = std::nullopt);
std::string expect_text(const Expect& e);
// A case block: its `case` line, its attributes, its steps framed for a
// target of `framing`; every line commented out when the case is skipped.
std::vector<std::string> case_lines(const Case& c, Framing framing);
// The whole script, header first.
std::string format(const Script& s);

}  // namespace mbc::conf::check
