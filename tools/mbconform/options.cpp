#include "options.h"

#include <fmt/core.h>

#include <ctime>
#include <filesystem>

#include "capture/pcap_tap.h"
#include "loader.h"
#include "targets/target.h"

namespace mbc::cli {

void add_target_options(CLI::App& cmd, TargetOptions& o, bool many, const std::string& out_help) {
  const std::string kinds = "ref:ID[?fault=NAME] | tcp://HOST:PORT?unit=N | rtu-tcp://HOST:PORT?unit=N | "
                            "rtu:///dev/tty?baud=B&unit=N | mbtls://HOST[:802]?cert=FILE&key=FILE&ca=FILE | plugin:PATH.so";
  if (many) {
    cmd.add_option("--target", o.targets, kinds + " (repeatable; default: every reference device)");
  } else {
    cmd.add_option_function<std::string>("--target", [&o](const std::string& t) { o.targets = {t}; }, kinds)->required();
  }
  cmd.add_option("--device", o.device, "ID: the spec (spec/devices/ID.yaml) of a live target (ref: targets carry their own)");
  cmd.add_option("--spec", o.spec_file, "FILE: a spec file describing a live target")->excludes(cmd.get_option("--device"));
  cmd.add_option("--out", o.out, out_help);
  cmd.add_option("--pcap", o.pcap, "FILE: also write every frame exchanged as pcapng (Wireshark; conformance/capture/README.md)");
  add_opt_ins(cmd, o);
  cmd.add_flag("--no-preflight", o.no_preflight, "live targets: skip the read-only check that the drive looks like the spec");
  cmd.add_flag("--progress", o.progress, "progress on stderr (done/total, rate, elapsed, ETA) even when stderr is not a terminal");
  cmd.add_option_function<int>(
         "--plugin-mem",
         [](int mib) { setenv("MBCONFORM_PLUGIN_MEM_MB", std::to_string(mib).c_str(), 1); },
         "plugin: targets: the plugin host's memory limit in MiB (default 1024; the URI's mem= wins)")
      ->check(CLI::Range(16, 1 << 20));
}

void add_opt_ins(CLI::App& cmd, TargetOptions& o) {
  cmd.add_flag("--allow-motion", o.policy.allow_motion, "live targets: allow writes to command and motion registers");
  cmd.add_flag("--allow-eeprom-writes", o.policy.allow_eeprom_writes, "live targets: allow writes that wear EEPROM/flash");
  cmd.add_flag("--allow-broadcast", o.policy.allow_broadcast, "live targets: allow writes to unit 0 (every drive on the line takes them)");
  cmd.add_flag("--allow-writes", o.policy.allow_writes,
               "live targets: allow writes to a map no manual states (imported, discovered, probed: --map auto) and to "
               "registers whose access is only inferred or observed");
  cmd.add_flag("--allow-disruptive", o.policy.allow_disruptive,
               "live targets: allow function codes whose effect the spec does not state (FC 08 restart, listen only, "
               "clears; user-defined codes 65-72, 100-110; FC 21; codes the spec's profile does not list)");
  cmd.add_flag("--allow-long-waits", o.allow_long_waits,
               fmt::format("frame scripts: allow a `wait` longer than {} s", kMaxWaitSeconds));
}

conf::SessionOptions session_options(const TargetOptions& o, const std::string& command, const std::string& out_dir) {
  conf::SessionOptions s;
  s.command = command;
  s.policy = o.policy;
  s.out_dir = out_dir;
  if (!o.pcap.empty()) s.wrap = [pcap = o.pcap](std::unique_ptr<conf::Target> t) { return conf::capture::tap_pcap(std::move(t), pcap); };
  return s;
}

Opened open_session(const std::optional<spec::Spec>& named, const std::string& uri, conf::SessionOptions options,
                    bool spec_optional) {
  Opened o;
  conf::Uri u = conf::parse_uri(uri);
  if (named || u.scheme == "ref") o.spec = std::make_unique<spec::Spec>(spec_for(named, uri));
  else if (u.scheme != "plugin" && !spec_optional)
    throw std::runtime_error("target " + uri + ": name its spec with --device ID or --spec FILE");
  o.session = std::make_unique<conf::Session>(uri, o.spec.get(), std::move(options));
  if (!o.spec && u.scheme == "plugin") {
    // A plugin names its device; it is not live, so the gate has nothing to hold.
    const std::string& id = o.session->info().device_id;
    if (id.empty() && !spec_optional) throw std::runtime_error("target " + uri + ": name its spec with --device ID or --spec FILE");
    if (!id.empty()) o.spec = std::make_unique<spec::Spec>(spec::load_spec_by_id(id));
  }
  if (!o.session->journal_path().empty())
    fmt::print(stderr, "journal: {} (if this command is killed: mbconform restore {})\n", o.session->journal_path(),
               o.session->journal_path());
  return o;
}

std::string prepare_live(conf::Session& session, const TargetOptions& o, std::vector<std::string>& notes) {
  if (!session.info().live) return "";
  if (std::string why = session.reachable(); !why.empty()) return why;
  if (!o.no_preflight) {
    std::string identity;
    if (std::string why = session.preflight(identity); !why.empty()) return why;
    if (!identity.empty()) notes.push_back("preflight: " + identity);
  }
  try {
    session.keep();
  } catch (const std::exception& e) {
    return fmt::format("cannot keep the registers' values: {}", e.what());
  }
  for (const auto& n : session.notes()) notes.push_back(n);
  return "";
}

std::vector<std::string> restore_and_say(conf::Session& session, const char* command) {
  if (session.journal_path().empty()) return {};
  conf::RestoreReport r;
  try {
    r = session.restore();
  } catch (const std::exception& e) {
    r.not_restored.push_back(fmt::format("restore stopped: {}", e.what()));
  }
  for (const auto& f : r.not_restored) fmt::print(stderr, "mbconform {}: NOT RESTORED: {}\n", command, f);
  for (const auto& n : r.notes) fmt::print(stderr, "mbconform {}: restore: {}\n", command, n);
  if (!r.not_restored.empty())
    fmt::print(stderr, "mbconform {}: the journal is {} (mbconform restore {} tries again)\n", command, session.journal_path(),
               session.journal_path());
  else if (r.kept)
    fmt::print(stderr, "restored: {} address(es) kept, {} written back, {} verified (journal {})\n", r.kept, r.restored,
               r.verified, session.journal_path());
  return r.not_restored;
}

std::vector<std::string> default_targets() {
  return {"ref:sihong-57hs-r", "ref:hsc60", "ref:hanstar-7trsm5740q", "ref:rieding-dhe", "ref:modbus-standard"};
}

const std::vector<std::string>& targets_or_default(TargetOptions& o) {
  if (o.targets.empty()) o.targets = default_targets();
  return o.targets;
}

std::optional<spec::Spec> named_spec(const TargetOptions& o) {
  if (!o.spec_file.empty()) {
    check_readable(o.spec_file, kMaxTextFileBytes, "--spec");  // a FIFO or a device would hang the reader
    auto lr = spec::load_spec_file(o.spec_file);
    if (!lr.ok()) {
      for (const auto& d : lr.diagnostics) fmt::print(stderr, "{}\n", d.str());
      throw std::runtime_error(o.spec_file + ": not a valid spec (mbconform spec check " + o.spec_file + ")");
    }
    return std::move(*lr.spec);
  }
  if (!o.device.empty()) return spec::load_spec_by_id(o.device);
  return std::nullopt;
}

spec::Spec spec_for(const std::optional<spec::Spec>& named, const std::string& uri, const std::string& device_id) {
  if (named) return *named;
  conf::Uri u = conf::parse_uri(uri);
  if (u.scheme == "ref") return spec::load_spec_by_id(u.path);
  if (!device_id.empty()) return spec::load_spec_by_id(device_id);
  throw std::runtime_error("target " + uri + ": name its spec with --device ID or --spec FILE");
}

void check_readable(const std::string& path, uintmax_t cap, const char* what) {
  std::error_code ec;
  auto st = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(st)) throw std::runtime_error(fmt::format("{} {}: no such file", what, path));
  if (!std::filesystem::is_regular_file(st))
    throw std::runtime_error(fmt::format("{} {}: not a regular file (a device or a pipe has no end to read to)", what, path));
  auto size = std::filesystem::file_size(path, ec);
  if (ec) throw std::runtime_error(fmt::format("{} {}: cannot read: {}", what, path, ec.message()));
  if (size > cap)
    throw std::runtime_error(fmt::format("{} {}: {} bytes, more than the {} such a file may have", what, path, size, cap));
}

}  // namespace mbc::cli
