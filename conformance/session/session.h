// The session: the one guarded path from every command to a target
// (README.md, "Live drives"; the seam is session/link.h).
//
//   - It opens the target with the line settings of the URI, else the
//     spec's (baud, parity, data and stop bits, the default unit), else the
//     standard's (MB-SL v1.02 §2.5.1: 19200 8E1), and says in one line what
//     it tried when the drive does not answer.
//   - Every frame passes the frame policy (policy/policy.h) before it goes out.
//   - On a live target, before the first write to any address, the value it
//     held is appended to the journal (session/journal.h) and flushed to
//     disk; keep() journals every register the command may write at once and
//     turns the spec's "do not persist" switch on.
//   - A command register (`access: command`) is written without a read
//     first: it is journaled as written, and the restore undoes it with the
//     spec's stop. A read-only register is never journaled.
//   - When the journal cannot be written (a full disk), the write it was to
//     guard is not sent and sending stops (stopped() says why).
//   - restore() puts every journaled address back (session/restore.h), from
//     the file and from what the journal kept in memory. `mbconform restore
//     JOURNAL` runs the same restore from the journal alone.
//   - A stop signal (session/signals.h) or the deadline ends the sending.
//
// Every command sends through the Session as a Link: run and replay through
// the runner, props and fuzz through check::Exchange, the map probe (run
// --map auto, spec discover) and the timing checks with the Link itself
// (reply_or_throw: a refused frame throws Refused, a stop Stopped).
#pragma once

#include <chrono>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "policy/policy.h"
#include "session/journal.h"
#include "session/link.h"
#include "session/restore.h"
#include "spec.h"

namespace mbc::conf {

struct SessionOptions {
  std::string command = "run";  // for messages ("mbconform run: ...") and the journal
  WritePolicy policy;  // the opt-ins (policy/policy.h)
  // Where the journal goes (the command's output directory); a live target
  // without one cannot be written (every write is refused).
  std::string out_dir;
  // After a stop signal, the next frame is refused as stopped (Sent::stopped;
  // props, fuzz, replay), and advance(), power_cycle(), trip_fault() and
  // restart() throw Stopped; false: the caller stops between its own steps (run).
  bool stop_mid_exchange = true;
  // No frame goes out after this (fuzz --duration, --deadline).
  std::optional<std::chrono::steady_clock::time_point> deadline;
  // Called after each frame sent, with the count so far (progress).
  std::function<void(uint64_t frames)> on_frame;
  // Wraps every target the session opens (--pcap: conformance/capture's tap).
  std::function<std::unique_ptr<Target>(std::unique_ptr<Target>)> wrap;
};

// Where each line setting of an opened target came from.
struct LineSettings {
  std::string uri;          // the URI with the settings filled in
  std::string tried;        // "9600 8N1, unit 1"
  std::string origin;       // "from the spec hsc60" | "from the URI" | "the standard's default (MB-SL v1.02 §2.5.1)" | mixed
  std::string spec_says;    // "the spec hsc60 says 9600 8N1, unit 1", or empty
};
// Fills in what the URI does not say from the spec, else the standard.
// Throws std::invalid_argument on a bad URI.
LineSettings line_settings(const std::string& uri, const spec::Spec* spec);

// The liveness probe: a read of one item, the first the profile can read
// (FC 03/04/01/02); any reply, even an exception, shows the target is there.
Bytes probe_request(const spec::Spec& s);

class Session final : public Link {
 public:
  // Opens the target. `spec` (may be null: nothing may be written) must
  // outlive the session. Throws std::invalid_argument (bad URI) or
  // std::runtime_error (cannot open; cannot create the journal).
  Session(const std::string& uri, const spec::Spec* spec, SessionOptions options);
  ~Session() override;  // restores what keep() or a write journaled, if restore() did not run
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  // ---- the Link ----
  const TargetInfo& info() const override { return inner_->info(); }
  Sent transact(uint8_t unit, std::span<const uint8_t> pdu, Target::Wait wait) override;
  Sent send_raw(std::span<const uint8_t> adu, std::optional<size_t> gap_after, Target::Wait wait) override;
  // Pipelined where the target pipelines (Modbus TCP): every request of the
  // batch passes the policy (and the journal) before the batch goes out; a
  // batch with a refused request goes one by one, so the refusal is that
  // request's, and stops there (fewer Sents than requests: the rest were not sent).
  std::vector<Sent> transact_all(std::span<const Target::Request> requests, size_t depth, Target::Wait wait) override;
  bool pipelines() const override { return inner_->pipelines(); }
  std::chrono::microseconds silence_window() const override { return inner_->silence_window(); }
  uint64_t late_replies() const override { return inner_->late_replies(); }
  std::optional<std::chrono::microseconds> split_gap() const override { return inner_->split_gap(); }
  void set_split_gap(std::chrono::microseconds g) override { inner_->set_split_gap(g); }
  bool reconnect() override { return inner_->reconnect(); }
  void advance(std::chrono::microseconds dt) override {
    if (opt_.stop_mid_exchange) check_running();
    inner_->advance(dt);
  }
  void power_cycle() override {
    if (opt_.stop_mid_exchange) check_running();
    inner_->power_cycle();
  }
  bool trip_fault() override {
    if (opt_.stop_mid_exchange) check_running();
    return inner_->trip_fault();
  }

  // ---- the command's side ----
  const LineSettings& line() const { return line_; }
  // The one line printed when the target does not answer at all: the
  // settings tried, where they came from, the spec's, the unit.
  std::string no_answer(const std::string& why) const;
  // Empty when a read the spec says is answered gets an answer (3 tries with
  // reconnects), else no_answer(...).
  std::string reachable();
  // A read-only check that the drive looks like the spec (--no-preflight
  // skips it): its FC 43/14 VendorName and ProductCode where the spec says
  // it answers them, else reads of registers spread over the spec's map (a
  // drive that refuses most of them is another drive). Empty when it looks
  // right, else one line; `identity` gets what was read, for the report.
  std::string preflight(std::string& identity);
  // Live targets: journals every register the command may write (read
  // first, fsync'd), then turns the "do not persist" switch on. Notes (what
  // could not be read) go to notes().
  void keep();
  const std::vector<std::string>& notes() const { return notes_; }
  // The journal (empty path when there is none: not a live target).
  const std::string& journal_path() const { return journal_.path(); }
  // Puts the drive back (idempotent). Marks the journal's end.
  RestoreReport restore();
  bool restored() const { return restored_; }

  // Starts the target afresh: a new in-process target at power-on (not
  // live: ref:, plugin), the same connection reopened for a live one. The
  // fuzzer's fresh runs and the properties' cases. Throws Stopped after a
  // stop or the deadline, std::runtime_error when it cannot be reopened.
  void restart();
  // What the frame policy judges this session's frames by (its makers ask
  // the same before they make a check).
  const PolicyFacts& policy_facts() const { return facts_; }
  // Frames sent and refused so far (progress, reports).
  uint64_t frames() const { return frames_; }
  uint64_t refused() const { return refused_; }
  // Whether sending stopped (signal or deadline), and why.
  std::optional<std::string> stopped() const;
  // Throws Stopped when sending stopped (for steps that send no frame).
  void check_running() const;

 private:
  // Why sending stopped, when it stops this frame (stop_mid_exchange).
  std::optional<std::string> stops_frames() const;
  // The policy, then the journal: why the frame may not go out, or nullopt.
  std::optional<Refusal> before_write(Target& t, uint8_t unit, std::span<const uint8_t> pdu);
  // Journals what a write to `unit` is about to change (live targets).
  std::optional<Refusal> journal_write(Target& t, uint8_t unit, std::span<const uint8_t> pdu);
  std::optional<Refusal> journal_range(Target& t, const WriteRange& w);
  // Records the drive's identity in the journal once, before the first value.
  void record_identity();
  // The journal's `control` record (the drive's control state), once.
  void record_control(Target& t);
  // After a write: the control's set-points it made 0 (PolicyFacts::zeroed).
  void note_zeroed(uint8_t unit, std::span<const uint8_t> pdu, const Reply& reply);
  void count_frame() {
    ++frames_;
    if (opt_.on_frame) opt_.on_frame(frames_);
  }

  const spec::Spec* spec_;
  SessionOptions opt_;
  LineSettings line_;
  std::unique_ptr<Target> inner_;
  PolicyFacts facts_;  // what the frame policy judges by
  Journal journal_;
  std::vector<std::string> notes_;
  bool restored_ = false;
  bool identity_recorded_ = false;
  uint64_t frames_ = 0, refused_ = 0;
};

}  // namespace mbc::conf
