// The seam between the checks and the thing under test (agreed between the
// guarded-session work and the one-check work; conformance/README.md).
//
//   check/ (one Step, one Expect, one judge, one exchange)
//      |  hands every frame to a Link
//   session/ (the frame policy, the journal, restore, signals, deadlines, progress)
//      |  owns the Target
//   targets/ (ref, tcp, rtu-tcp, rtu, plugin, tls)
//
// Every command that touches a target (run, props, fuzz, replay, spec
// discover, the --map auto probe) reaches it through a Link and never through
// a Target directly. The session's Link asks the frame policy (policy/policy.h) about each frame before
// it goes out and journals the original value of anything it writes; a frame
// the policy refuses is not sent and comes back as a Reply with `refused` set
// (the check records it as skipped with that reason, never as a verdict).
// DirectLink passes frames straight to a Target: for in-process reference
// targets in unit tests only.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "policy/policy.h"
#include "targets/target.h"

namespace mbc::conf {

// A frame the policy held back, as an exception (reply_or_throw): the frame
// cannot be sent with these opt-ins (replay reports "cannot run"; a property
// case is discarded).
struct Refused : std::logic_error {
  Refusal refusal;
  explicit Refused(Refusal r) : std::logic_error("refused by the frame policy: " + r.reason), refusal(std::move(r)) {}
};
// Sending stopped: a stop signal, or the command's deadline ran out.
struct Stopped : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct Sent {
  Reply reply;                   // what came back (empty frame on silence or refusal)
  std::optional<Refusal> refused;  // set: nothing was sent
  bool lost = false;             // the target is gone (transport failed past a bounded reconnect)
  bool stopped = false;          // refused because sending stopped (a stop signal, the deadline): refused says why
};

// The reply of a Sent, for code that reads a reply or an exception: a
// frame sending stopped for throws Stopped, one the policy held back
// Refused, a lost target std::runtime_error.
Reply reply_or_throw(Sent sent, const TargetInfo& info);

class Link {
 public:
  virtual ~Link() = default;
  virtual const TargetInfo& info() const = 0;

  // A well-formed request `pdu` to `unit` (0 = broadcast).
  virtual Sent transact(uint8_t unit, std::span<const uint8_t> pdu, Target::Wait wait) = 0;
  // Bytes exactly as given (a whole ADU in the target's framing, possibly
  // malformed); the policy judges what a receiver could take from them.
  virtual Sent send_raw(std::span<const uint8_t> adu, std::optional<size_t> gap_after, Target::Wait wait) = 0;
  // Several requests, one Sent each, in order: pipelined where the target
  // pipelines (Modbus TCP, Target::transact_all), once every request of the
  // batch may go out; else one transact after another, up to the first
  // refused (fewer Sents than requests: the rest were not sent).
  virtual std::vector<Sent> transact_all(std::span<const Target::Request> requests, size_t depth, Target::Wait wait) = 0;
  virtual bool pipelines() const = 0;

  // Pass-throughs to the Target (see targets/target.h).
  virtual std::chrono::microseconds silence_window() const = 0;
  virtual uint64_t late_replies() const = 0;
  virtual std::optional<std::chrono::microseconds> split_gap() const = 0;
  virtual void set_split_gap(std::chrono::microseconds) = 0;
  virtual bool reconnect() = 0;
  virtual void advance(std::chrono::microseconds dt) = 0;
  virtual void power_cycle() = 0;
  virtual bool trip_fault() = 0;
};

// No policy, no journal: a Target as a Link (reference targets in tests,
// and props::source_for). It borrows the target or owns it; replace() puts
// a fresh one in (an in-process target at power-on).
class DirectLink final : public Link {
 public:
  explicit DirectLink(Target& t) : t_(&t) {}
  explicit DirectLink(std::unique_ptr<Target> t) : owned_(std::move(t)), t_(owned_.get()) {}
  void replace(std::unique_ptr<Target> t) {
    owned_ = std::move(t);
    t_ = owned_.get();
  }
  Target& target() { return *t_; }
  const TargetInfo& info() const override { return t_->info(); }
  Sent transact(uint8_t unit, std::span<const uint8_t> pdu, Target::Wait wait) override {
    t_->set_wait(wait);
    return Sent{t_->transact(unit, pdu), std::nullopt, false};
  }
  Sent send_raw(std::span<const uint8_t> adu, std::optional<size_t> gap_after, Target::Wait wait) override {
    t_->set_wait(wait);
    return Sent{t_->send_raw(adu, gap_after), std::nullopt, false};
  }
  std::vector<Sent> transact_all(std::span<const Target::Request> requests, size_t depth, Target::Wait wait) override {
    t_->set_wait(wait);
    std::vector<Sent> out;
    for (auto& r : t_->transact_all(requests, depth)) out.push_back(Sent{std::move(r), std::nullopt, false});
    return out;
  }
  bool pipelines() const override { return t_->pipelines(); }
  std::chrono::microseconds silence_window() const override { return t_->silence_window(); }
  uint64_t late_replies() const override { return t_->late_replies(); }
  std::optional<std::chrono::microseconds> split_gap() const override { return t_->split_gap(); }
  void set_split_gap(std::chrono::microseconds g) override { t_->set_split_gap(g); }
  bool reconnect() override { return t_->reconnect(); }
  void advance(std::chrono::microseconds dt) override { t_->advance(dt); }
  void power_cycle() override { t_->power_cycle(); }
  bool trip_fault() override { return t_->trip_fault(); }

 private:
  std::unique_ptr<Target> owned_;
  Target* t_;
};

inline Reply reply_or_throw(Sent sent, const TargetInfo& info) {
  if (sent.refused) {
    if (sent.stopped) throw Stopped(sent.refused->reason);
    throw Refused(*sent.refused);
  }
  if (sent.lost) throw std::runtime_error("the target " + info.uri + " was lost");
  return std::move(sent.reply);
}

}  // namespace mbc::conf
