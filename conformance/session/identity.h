// The one reading of what a drive is, for the three that ask it: the
// preflight before the first write (Session::preflight), the journal's
// header that a restore checks (journal_identity) and `mbconform scan`,
// which matches each unit it finds against the known specs.
//
// FC 43/14's VendorName and ProductCode where the spec says the drive
// answers them (MBAP v1.1b3 §6.21); else reads of registers spread over the
// spec's map whose readability the spec states. A reading only inferred,
// observed or printed two ways identifies nothing (a Hanstar answers FC 03
// only where its table 12 prints it, not at 3000-3016, documented for FC
// 06/16), and one declaration is one sample (a reserved block of 39
// registers is one). What each reader makes of the reads is its own: the
// preflight refuses a drive that refuses most of them, the journal keeps
// which were answered (not their values, which change), the scan scores
// the values against the stated ranges.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "modbus/pdu.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf {

// Sends one read-only request to the drive and returns its reply; nullopt
// when it did not go out or could not be read (`error` says why: the policy
// held it back, the line threw).
using IdentityAsk = std::function<std::optional<Reply>(const Bytes& pdu, std::string& error)>;

// One register read for the identity.
struct IdentityRead {
  const spec::Register* reg = nullptr;
  uint8_t fc = 0;  // 03 or 04
  // answered: a normal reply of the size the register has; malformed: a
  // reply of another shape, or a frame that does not decode (still this
  // drive answering); not_sent: `error`.
  enum class Kind { answered, exception, silent, malformed, not_sent } kind = Kind::silent;
  uint8_t exception = 0;
  Bytes pdu;          // the reply's PDU as it came (empty: none decoded)
  std::string error;  // not_sent: why
  // Speaks against the identity: silence, exception 01 or 02 (the address
  // or the function refused), or a read that could not be made.
  bool refused() const;
  // The register's value (answered, one word).
  std::optional<uint16_t> word() const;
};

struct Identity {
  bool by_fc43 = false;               // FC 43/14 was asked
  std::map<int, std::string> objects;  // what it gave: 00 VendorName, 01 ProductCode, 02 Revision (empty: nothing)
  std::vector<IdentityRead> reads;     // else: the registers read
  // "FC 43/14: VendorName "X", ProductCode "Y", Revision "Z"".
  std::string objects_text() const;
};

// Whether the spec says the drive answers FC 43/14 with a ProductCode to compare.
bool identifies_by_fc43(const spec::Spec& s);
// The registers that identify a drive of `s`: holding or input, readable as
// the spec states, read by a function code the profile states, not a command
// register; one per declaration, in the spec's order. `stated_only` false:
// also those whose readability is only inferred (the journal compares a
// drive with itself, so an inferred reading still tells two drives apart;
// an imported map states none).
std::vector<const spec::Register*> identity_registers(const spec::Spec& s, bool stated_only = true);

struct IdentityOptions {
  size_t samples = 8;   // registers read, spread over identity_registers()
  int attempts = 1;     // tries of a read that got nothing
  bool fc43 = true;     // ask FC 43/14 where the spec says it is answered
  bool stated_only = true;  // identity_registers()'s
};
// Reads the identity of the drive `ask` reaches, as `s` describes it.
Identity read_identity(const spec::Spec& s, const IdentityAsk& ask, const IdentityOptions& o = {});

}  // namespace mbc::conf
