#include "options.h"

#include <fmt/core.h>

#include <ctime>

#include "loader.h"
#include "targets/target.h"

namespace mbc::cli {

void add_target_options(CLI::App& cmd, TargetOptions& o, bool many, const std::string& out_help) {
  const std::string kinds = "ref:ID[?fault=NAME] | tcp://HOST:PORT?unit=N | rtu-tcp://HOST:PORT?unit=N | "
                            "rtu:///dev/tty?baud=B&unit=N | plugin:PATH.so";
  if (many) {
    cmd.add_option("--target", o.targets, kinds + " (repeatable; default: every reference device)");
  } else {
    cmd.add_option_function<std::string>("--target", [&o](const std::string& t) { o.targets = {t}; }, kinds)->required();
  }
  cmd.add_option("--device", o.device, "ID: the spec (spec/devices/ID.yaml) of a live target (ref: targets carry their own)");
  cmd.add_option("--spec", o.spec_file, "FILE: a spec file describing a live target")->excludes(cmd.get_option("--device"));
  cmd.add_option("--out", o.out, out_help);
  cmd.add_option("--pcap", o.pcap, "FILE: also write every frame exchanged as pcapng (Wireshark; conformance/capture/README.md)");
  cmd.add_flag("--allow-motion", o.policy.allow_motion, "live targets: allow writes to command and motion registers");
  cmd.add_flag("--allow-eeprom-writes", o.policy.allow_eeprom_writes, "live targets: allow writes that wear EEPROM/flash");
  cmd.add_flag("--allow-broadcast", o.policy.allow_broadcast, "live targets: allow writes to unit 0 (every drive on the line takes them)");
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

std::string utc_now(const char* format) {
  std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, format, &tm);
  return buf;
}

}  // namespace mbc::cli
