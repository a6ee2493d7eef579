// What every case generator shares: turning a register's value into the
// words on the wire (type, word order), building the read and write steps a
// profile allows, and turning the spec's exception policy into an
// expectation. Only the spec and the Modbus standard feed these.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "cases/case.h"
#include "check/judge.h"

namespace mbc::conf::cases {

// "sihong-57hs-r §6.2.4"; standard citations ("MBAP 6.3") stay as printed.
std::string clause(const spec::Spec&, const std::string& section);

// "0x0020".
std::string hex16(unsigned v);

// The lowest and highest raw value the register's type can carry.
int64_t type_min(const spec::Register&);
int64_t type_max(const spec::Register&);

// The words a raw value occupies, in wire order (lower address first),
// per the register's word order.
std::vector<uint16_t> encode(const spec::Register&, int64_t raw);

// Reading the register (FC 03/04/01/02 by table); nullopt when the profile
// has no read function for its table.
std::optional<Step> read_step(const GenContext&, const spec::Register&, Expect e);
// A read of `quantity` items from `address` of `table`.
std::optional<Step> read_range_step(const GenContext&, spec::Table, uint16_t address, uint16_t quantity, Expect e);

// Writing `words` to the register whole (FC 06 for one word when the profile
// has it, else FC 16; FC 05/15 for coils); nullopt when the profile cannot.
// `e` defaults to the standard's normal reply (echo for 05/06, address and
// quantity for 15/16: MBAP v1.1b3 §6.5, §6.6, §6.11, §6.12).
std::optional<Step> write_step(const GenContext&, const spec::Register&, const std::vector<uint16_t>& words,
                               std::optional<Expect> e = std::nullopt);
// The normal reply MBAP v1.1b3 §6 prescribes for a write request PDU.
Expect write_echo(const Bytes& request_pdu);

// The spec's policy for a violation as an expectation. Where the manual is
// silent (unspecified) the standard's answer (modbus-standard's policy) is
// the expectation and `level` becomes OBSERVED.
struct PolicyExpect {
  Expect expect;
  Level level = Level::must;
  std::string clause;
  std::string erratum;
};
PolicyExpect policy_expect(const GenContext&, spec::Violation);

// Why the case may not write the register on this target, or empty.
std::string write_forbidden(const GenContext&, const spec::Register&);

// Whether the profile supports a function code.
bool has_fc(const spec::Spec&, int fc);

// A register that reads and writes plainly (rw, holding, one word, not a
// line setting, writable by policy) for cases that need any register.
const spec::Register* plain_register(const GenContext&);
// Two different values plain_register()'s register accepts: its range's
// bounds, or 0 and 1 when it states no range.
std::pair<int64_t, int64_t> plain_values(const spec::Register&);
// Records what a case using plain_register()'s register and plain_values()
// relies on (cases/facts.h): that it reads, writes, and its range.
void plain_relies(std::vector<Reliance>&, const spec::Register&);

// Whether a step sends a request to unit 0 that is not a read (check/check.h).
using check::is_broadcast_write;

// The broadcast writes the cases would send, one line each ("<case id>:
// write 0x0048 = ..."): what every drive on the line would receive (--plan).
std::vector<std::string> planned_broadcast_writes(const std::vector<Case>& cases);

// "exception 03", "echo", ... (check/judge.h)
using check::describe;

Expect exact(Bytes pdu, std::string text = "");
Expect exception(uint8_t code, std::string text = "");
Expect silence(std::string text = "");
Expect normal(std::string text = "");

}  // namespace mbc::conf::cases
