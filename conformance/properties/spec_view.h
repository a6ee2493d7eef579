// What a device's spec says, in the shape the properties ask it: which
// registers a property may write, which values are in and out of range,
// what the exception policy answers, how the register image is read. Only
// the spec (spec/loader/spec.h) and the Modbus standard are consulted here;
// nothing in this file knows the reference devices.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "modbus/hex.h"
#include "policy/policy.h"
#include "safety/safety.h"
#include "spec.h"
#include "targets/target.h"

namespace mbc::conf::props {

// What the spec's exception policy lets a device answer to one violation.
struct Expected {
  enum class Kind { exception, silence, refused };  // refused: policy unspecified, any exception or silence
  Kind kind = Kind::refused;
  int code = 0;
  std::vector<Expected> either = {};  // the manual prints two readings: any of them passes
  std::string text() const;  // "exception 03", "silence", "an exception or silence (policy unspecified)"
  // Whether `reply` (a judged reply, or silence) is allowed.
  bool allows(const Reply& reply) const;
};
// What one policy entry (cases/facts.h policy()) lets a device answer; an
// inferred or observed answer is not held against the device (any refusal).
Expected expected_of(const spec::PolicyEntry&);

class SpecView {
 public:
  SpecView(const spec::Spec& spec, const TargetInfo& target, const WritePolicy& policy);

  const spec::Spec& spec() const { return *spec_; }
  // What the frame policy judges by on this target (the spec, the target, the opt-ins).
  const PolicyFacts& policy_facts() const { return policy_facts_; }

  // Holding registers a property may write and read back: access rw, not a
  // serial setting (baud, slave id: writing one can cut the master off),
  // allowed by the frame policy on this target.
  const std::vector<const spec::Register*>& writable() const { return writable_; }
  // Holding registers with access ro (for "write to read-only").
  const std::vector<const spec::Register*>& read_only() const { return read_only_; }
  // The registers the image compares: every readable holding register on a
  // reference target (nothing changes without advance()); on a live device
  // only rw ones (measurements drift by themselves).
  const std::vector<const spec::Register*>& image_registers() const { return image_; }

  // In the profile: the spec answers it as a supported function.
  bool in_profile(int fc) const { return spec_->profile.function(fc) != nullptr; }
  // In the profile and not only inferred to be (spec/README.md): what a
  // property may send and hold the device to.
  bool supports(int fc) const {
    const spec::FunctionCode* f = spec_->profile.function(fc);
    return f && !f->basis_of("supported").is_inferred();
  }
  // Why broadcast writes may not be sent on this target (Modbus TCP, or a
  // live target without --allow-broadcast: the frame policy), or empty.
  const std::string& broadcast_unavailable() const { return broadcast_unavailable_; }
  // The quantity limit of FC 03/04/16: the spec's max_quantity capped by the
  // standard's (MBAP v1.1b3 §6.3: 125, §6.12: 123).
  int quantity_limit(int fc) const;
  // A function code the profile does not list (1..127), if any.
  std::vector<int> unsupported_functions() const;
  // The inferred or observed facts the properties do not hold against the
  // device (spec/README.md): "register 0x0024 range: inferred (...)". A run
  // reports them with its outcome.
  const std::vector<std::string>& not_held() const { return not_held_; }
  // The frames the frame policy refused a property's generator (a case
  // discarded before it sent anything, unlike a frame held back at sending):
  // each refusal's opt-in, how often. A property that could not generate
  // enough cases for want of them is skipped for want of that opt-in
  // (properties.cpp). Kept across runs, as the view is.
  void note_refusal(const Refusal& r) const {
    if (!r.opt_in.empty()) ++refused_opt_ins_[r.opt_in];
  }
  const std::map<std::string, int>& refused_opt_ins() const { return refused_opt_ins_; }

  Expected expected(spec::Violation v) const;

  // In range: the register's range, else its enum's values, else the type's
  // (float32: not NaN and within range).
  bool in_range(const spec::Register& r, uint32_t raw) const;
  // Raw values (2-word: as one 32-bit value) to try: in range / out of range.
  std::vector<uint32_t> boundary_values(const spec::Register& r) const;
  std::vector<uint32_t> out_of_range_values(const spec::Register& r) const;
  // The words of `raw` in the register's word order (MBAP §4.2 big-endian per word).
  std::vector<uint16_t> words_of(const spec::Register& r, uint32_t raw) const;
  uint32_t raw_of(const spec::Register& r, std::span<const uint16_t> words) const;
  // The default value as raw bits, if the spec prints one.
  std::optional<uint32_t> default_raw(const spec::Register& r) const;

  // Request PDUs that write `raw` to r: FC 06 for one word when the profile
  // has it (else FC 16), FC 16 for two.
  Bytes write_request(const spec::Register& r, uint32_t raw, bool prefer_fc16 = false) const;
  // Read requests covering the image registers (runs of contiguous mapped
  // readable addresses, within the FC 03 limit, never splitting a register).
  const std::vector<std::pair<uint16_t, uint16_t>>& image_reads() const { return image_reads_; }

 private:
  const spec::Spec* spec_;
  PolicyFacts policy_facts_;
  std::vector<const spec::Register*> writable_, read_only_, image_;
  std::vector<std::string> not_held_;
  std::vector<std::pair<uint16_t, uint16_t>> image_reads_;
  std::string broadcast_unavailable_;
  mutable std::map<std::string, int> refused_opt_ins_;
};

// Sends one request PDU to the unit and returns the reply (a Session's send,
// so every frame lands in the counterexample).
using Transact = std::function<Reply(std::span<const uint8_t> pdu, const std::string& note)>;

// The register image read through a target: address -> word, or an error
// message (a read refused, a malformed reply).
struct Image {
  std::map<uint16_t, uint16_t> words;
  std::string error;
  std::vector<std::string> differences(const Image& after) const;  // "0x0020: 1000 -> 1001"
};
Image read_image(const Transact& transact, const SpecView& view);

// Reads one register (all its words) with FC 03.
struct ReadResult {
  std::optional<uint32_t> raw;
  std::string error;
};
ReadResult read_register(const Transact& transact, const SpecView& view, const spec::Register& r);

}  // namespace mbc::conf::props
