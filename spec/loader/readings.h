// "The other reading" (issue 26): every fact of a spec that is inferred,
// observed or printed two ways can be read another way by a drive that does
// what its manual prints. other_reading() gives the spec (and, for a printed
// frame, the answer) of a device that takes the other reading of one such
// fact; the reference target serves it as `ref:ID?reading=KEY`, and a test
// runs every MUST case against every variant: none may fail, since a MUST
// never rests on a contested fact.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "modbus/bytes.h"
#include "spec.h"

namespace mbc::spec {

// One contested fact and its variant's key: "0x0024.range",
// "0x00E0.persistence_unless", "fc16.supported", "fc16.max_quantity",
// "policy.crc_error", "example.start-homing", "address.plus-one-parameters"
// (every register an erratum contesting `address` names sits one above its
// printed address).
struct Reading {
  std::string key;
  std::string fact;   // as cases name it ("register 0x0024 range", "FC 16 supported", ...)
  Basis basis = Basis::stated;
  std::string other;  // the other reading, in words
  // The errata the fact's doubt comes from: its `either`'s erratum, or those
  // its owner cites that contest it (every behavioural erratum has a variant).
  std::vector<std::string> errata;
};

// Every inferred, observed or either fact of `s` that a device can read
// another way, in spec order.
std::vector<Reading> contested_readings(const Spec& s);

// A device that takes the other reading: its spec, and the answers to
// printed frames it gives differently (request PDU -> reply PDU; no reply
// when empty). Throws std::invalid_argument for a key that names no
// contested fact.
struct Variant {
  Spec spec;
  std::vector<std::pair<Bytes, std::optional<Bytes>>> answers;
  std::string describe;
};
Variant other_reading(const Spec& s, const std::string& key);

}  // namespace mbc::spec
