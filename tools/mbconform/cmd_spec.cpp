// mbconform spec check | dump | errata | list | import | export, and --spec-dir
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>

#include <fmt/core.h>
#include <fmt/format.h>

#include "commands.h"
#include "dump.h"
#include "errata.h"
#include "cases/case.h"
#include "cases/facts.h"
#include "erratum_extra.h"
#include "exchange.h"
#include "loader.h"
#include "conventions.h"
#include "map/map.h"
#include "options.h"
#include "runner/runner.h"
#include "session/progress.h"
#include "session/session.h"
#include "session/signals.h"
#include "targets/target.h"

namespace mbc::cli {
namespace {

namespace fs = std::filesystem;

// Exit 1 when a spec has errors; 2 when a file cannot be read at all (the
// check could not be done).
int run_check(const std::vector<std::string>& files, bool quiet) {
  int failed = 0;
  for (const auto& f : files) {
    std::error_code ec;
    if (!fs::is_regular_file(f, ec) || !std::ifstream(f)) {
      std::cerr << fmt::format("{}:0:0: error: file: cannot read {}\n", f, fs::exists(f, ec) ? "it" : "it: no such file");
      return kExitUsage;
    }
    auto r = spec::load_spec_file(f);
    for (const auto& d : r.diagnostics) std::cerr << d.str() << "\n";
    if (r.ok()) {
      if (!quiet)
        std::cout << fmt::format("{}: ok ({} registers, {} examples, {} errata)\n", f, r.spec->registers.size(),
                                 r.spec->examples.size(), r.spec->errata.size());
    } else {
      ++failed;
      if (r.diagnostics.empty()) std::cerr << f << ":0:0: error: internal: spec did not load\n";
    }
  }
  if (failed) std::cerr << fmt::format("{} of {} spec files have errors\n", failed, files.size());
  return failed ? kExitFailed : kExitOk;
}

// Accepts an id (spec/devices/<id>.yaml) or a path.
spec::Spec load_id_or_path(const std::string& what) {
  std::string path = what;
  if (what.find('/') == std::string::npos && what.find(".yaml") == std::string::npos) path = spec::spec_path(what);
  auto r = spec::load_spec_file(path);
  if (!r.ok()) {
    std::string msg = "spec '" + what + "' does not load";
    for (const auto& d : r.diagnostics) msg += "\n" + d.str();
    throw std::runtime_error(msg);
  }
  return std::move(*r.spec);
}

bool write_file(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
  return bool(out);
}

// The cases of a spec, as a reference target runs them, that are OBSERVED
// only because a fact they rely on is inferred (cases/facts.h), with the facts.
nlohmann::json observed_by_inference(const spec::Spec& s, const spec::Spec& standard) {
  conf::TargetInfo info;
  info.kind = conf::TargetKind::ref;
  info.uri = "ref:" + s.device.id;
  info.unit = uint8_t(s.serial.slave_default.value_or(s.serial.slave_min));
  info.virtual_clock = info.power_cycle = info.raw = true;
  info.device_id = s.device.id;
  conf::GenContext g{s, info, {}, &standard, std::nullopt};
  nlohmann::json out = nlohmann::json::array();
  for (const auto& c : conf::all_cases(g)) {
    if (!c.level_if_stated) continue;
    nlohmann::json facts = nlohmann::json::array();
    for (const auto& r : conf::facts::all_relies(c)) {
      if (!spec::demotes(r.basis)) continue;
      nlohmann::json f{{"fact", r.fact}, {"basis", spec::to_string(r.basis.basis)}, {"why", r.basis.why}, {"section", r.basis.section}};
      if (!r.basis.searched.empty()) f["searched"] = r.basis.searched;
      facts.push_back(std::move(f));
    }
    out.push_back({{"case", c.id}, {"level_if_stated", conf::to_string(*c.level_if_stated)}, {"facts", facts}});
  }
  return out;
}

int run_errata(std::vector<std::string> ids, const std::string& out_dir) {
  if (ids.empty()) ids = spec::spec_ids();
  spec::Spec standard = load_id_or_path("modbus-standard");
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) throw std::runtime_error("cannot create " + out_dir + ": " + ec.message());
  for (const auto& id : ids) {
    spec::Spec s = load_id_or_path(id);
    auto report = spec::errata_report(s, standard, observed_by_inference(s, standard));
    fs::path base = fs::path(out_dir) / s.device.id;
    if (!write_file(base.string() + ".json", report.dump(2) + "\n") ||
        !write_file(base.string() + ".md", spec::errata_markdown(report)))
      throw std::runtime_error("cannot write " + base.string() + ".{json,md}");
    const auto& sum = report["summary"];
    std::cout << fmt::format("{}.md: {} frames ({} bad CRC), {} errata ({} contradictions, {} typos and nits), {} deviations\n",
                             base.string(), sum["frames"].get<int>(), sum["frames_bad_crc"].get<int>(), sum["errata"].get<int>(),
                             sum["contradictions"].get<int>(), sum["typos"].get<int>() + sum["nits"].get<int>(),
                             sum["deviations"].get<int>());
  }
  return kExitOk;
}

bool valid_id(const std::string& id) {
  if (id.empty() || !std::isalnum(static_cast<unsigned char>(id[0]))) return false;
  for (char c : id)
    if (!(std::islower(static_cast<unsigned char>(c)) || std::isdigit(static_cast<unsigned char>(c)) || c == '-')) return false;
  return true;
}

int run_import(const std::string& csv_file, const std::string& wb_file, std::string id, std::string out) {
  if (csv_file.empty() == wb_file.empty()) throw std::runtime_error("give one of --csv FILE and --wb-template FILE");
  const std::string& csv = csv_file.empty() ? wb_file : csv_file;
  // The importer's own cap (exchange.h), so that a file over it is refused
  // before it is read, with the one line and exit code of every other reader.
  check_readable(csv, exchange::kMaxImportBytes, csv_file.empty() ? "--wb-template" : "--csv");
  std::ifstream in(csv, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open " + csv);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  // `spec check` wants the file named after the id (id-matches-file): with
  // --out and no --id, the id is the file's name; a different --id is said.
  const std::string out_stem = out.empty() || out == "-" ? "" : fs::path(out).stem().string();
  const bool out_yaml = !out_stem.empty() && fs::path(out).extension() == ".yaml";
  if (id.empty() && out_yaml) {
    if (!valid_id(out_stem))
      throw std::runtime_error(fmt::format("--out {}: a spec's file is ID.yaml with ID [a-z0-9][a-z0-9-]*; name it so, or give --id", out));
    id = out_stem;
  }
  if (id.empty() && !wb_file.empty()) id = exchange::wb_template_id(text);
  if (id.empty()) throw std::runtime_error("--id ID is needed (the new spec's id, [a-z0-9][a-z0-9-]*)");
  if (!valid_id(id)) throw std::runtime_error("--id '" + id + "': a spec id is [a-z0-9][a-z0-9-]*");
  if (!out_stem.empty() && (out_stem != id || !out_yaml))
    std::cerr << fmt::format("{}: warning: the spec's id is {}, so `spec check` wants the file named {}.yaml (id-matches-file); "
                             "rename it, or import with --id {}\n",
                             out, id, id, valid_id(out_stem) ? out_stem : "ID");
  auto r = wb_file.empty() ? exchange::import_csv(text, csv, id) : exchange::import_wb_template(text, csv, id);
  // The importer caps its own lists (the first 20, then a count: exchange.h).
  for (const auto& w : r.warnings) std::cerr << w << "\n";
  // What each register's name made of it: the roles a live run guards.
  if (r.errors.empty()) std::cerr << exchange::classification_table(r);
  for (const auto& e : r.errors) std::cerr << e << "\n";
  if (!r.errors.empty()) {
    std::cerr << fmt::format("{}: {} error{}; nothing written\n", csv, r.error_count, r.error_count == 1 ? "" : "s");
    return kExitFailed;
  }
  if (out.empty()) out = id + ".yaml";
  if (out == "-") {
    std::cout << r.yaml;
  } else {
    if (!write_file(out, r.yaml)) throw std::runtime_error("cannot write " + out);
    std::cerr << fmt::format("{}: spec skeleton of {} ({} registers)\n", out, id, r.registers);
  }
  return kExitOk;
}

int run_export(const std::string& what, const std::string& format, const std::string& out,
               const exchange::HomeAssistantOptions& ha) {
  spec::Spec s = load_id_or_path(what);
  if (!ha.only.empty()) {
    size_t kept = std::count_if(s.registers.begin(), s.registers.end(), [&](const auto& r) { return exchange::register_matches(r, ha.only); });
    if (kept == 0) throw std::runtime_error(fmt::format("--only {}: matches none of {}'s {} registers", fmt::join(ha.only, ","), s.device.id, s.registers.size()));
  }
  std::string text = format == "csv"              ? exchange::export_csv(s)
                     : format == "home-assistant" ? exchange::export_home_assistant(s, ha)
                     : format == "wb-template"    ? exchange::export_wb_template(s)
                                                  : exchange::export_edgex(s);
  if (out.empty() || out == "-") {
    std::cout << text;
  } else if (!write_file(out, text)) {
    throw std::runtime_error("cannot write " + out);
  }
  return kExitOk;
}

}  // namespace

void add_spec_commands(CLI::App& app, int& exit_code) {
  auto* spec_cmd = app.add_subcommand("spec", "Check, dump and report on device specs (spec/README.md)");
  spec_cmd->require_subcommand(1);

  auto* check = spec_cmd->add_subcommand("check", "Validate spec files against the schema and the semantic rules");
  static std::vector<std::string> check_files;
  static bool quiet = false;
  check->add_option("files", check_files, "spec files (default: every spec in spec/devices)");
  check->add_flag("-q,--quiet", quiet, "print only errors");
  check->callback([&] {
    std::vector<std::string> files = check_files;
    if (files.empty())
      for (const auto& f : spec::spec_files()) files.push_back(f.path);
    exit_code = run_check(files, quiet);
  });

  auto* dump = spec_cmd->add_subcommand("dump", "Print the resolved spec (JSON; format in spec/README.md)");
  static std::string dump_id;
  static bool as_json = true;
  dump->add_option("id", dump_id, "device id or spec file")->required();
  dump->add_flag("--json", as_json, "JSON output (the only format)");
  dump->callback([&] {
    std::cout << spec::to_json(load_id_or_path(dump_id)).dump(2) << "\n";
    exit_code = kExitOk;
  });

  auto* errata = spec_cmd->add_subcommand("errata", "Write reports/manuals/<id>.md and .json");
  static std::vector<std::string> errata_ids;
  static std::string errata_out = "reports/manuals";
  errata->add_option("ids", errata_ids, "device ids (default: all)");
  errata->add_option("--out", errata_out, "output directory")->capture_default_str();
  errata->callback([&] { exit_code = run_errata(errata_ids, errata_out); });

  auto* import = spec_cmd->add_subcommand(
      "import", "Turn a register map (a vendor's CSV sheet, a wb-mqtt-serial device template) into a spec (spec/README.md)");
  static std::string import_csv_file, import_wb_file, import_id, import_out;
  import->add_option("--csv", import_csv_file, "the register map (CSV with a header row; UTF-8, or GBK as Chinese Excel saves it)");
  import->add_option("--wb-template", import_wb_file, "a wb-mqtt-serial device template (JSON)");
  import->add_option("--id", import_id, "the new spec's id ([a-z0-9-]+; a template's own id by default)");
  import->add_option("--out", import_out, "the spec file to write (default ID.yaml; - for stdout)");
  import->callback([&] { exit_code = run_import(import_csv_file, import_wb_file, import_id, import_out); });

  auto* exp = spec_cmd->add_subcommand("export", "Write a spec's register map for another tool");
  static std::string export_id, export_format, export_out;
  exp->add_option("id", export_id, "device id or spec file")->required();
  exp->add_option("--format", export_format, "csv | home-assistant | edgex | wb-template")
      ->required()
      ->check(CLI::IsMember({"csv", "home-assistant", "edgex", "wb-template"}));
  exp->add_option("--out", export_out, "the file to write (default: stdout)");
  static exchange::HomeAssistantOptions ha;
  exp->add_option("--only", ha.only,
                  "home-assistant: only these registers: addresses (0x0044), ranges (0x0040-0x004F), globs on key or name (*speed*)")
      ->delimiter(',');
  exp->add_option("--scan-interval", ha.fast_scan, "home-assistant: seconds between reads of read-only registers")
      ->capture_default_str()->check(CLI::Range(1, 86400));
  exp->add_option("--settings-scan-interval", ha.slow_scan, "home-assistant: seconds between reads of writable settings")
      ->capture_default_str()->check(CLI::Range(1, 86400));
  exp->callback([&] { exit_code = run_export(export_id, export_format, export_out, ha); });

  auto* discover = spec_cmd->add_subcommand(
      "discover", "Probe a live target's map with reads (never writes) and write a spec skeleton whose facts are observed");
  static std::string discover_target, discover_out, discover_id;
  static int discover_budget = conf::map::kDefaultBudget;
  discover->add_option("--target", discover_target, "tcp://HOST:PORT?unit=N | rtu-tcp://... | rtu:///dev/tty...")->required();
  discover->add_option("--out", discover_out, "the spec file to write")->required();
  discover->add_option("--id", discover_id, "the device id to write (default: the --out file's name, as spec check requires)");
  discover->add_option("--map-budget", discover_budget, "the most read requests the probe sends")->check(CLI::Range(1, 1000000));
  static std::optional<std::chrono::milliseconds> discover_time;
  add_map_time_option(discover, discover_time);
  static bool discover_progress = false, discover_quiet = false;
  discover->add_flag("--progress", discover_progress, "progress on stderr (requests sent of the budget, rate, ETA) even when it is not a terminal");
  discover->add_flag("-q,--quiet", discover_quiet, "no progress");
  discover->callback([&] {
    try {
      // Through a session with no spec: the frame policy lets nothing but reads out.
      conf::install_stop_signals();
      conf::SessionOptions so;
      so.command = "spec discover";
      conf::Session session(discover_target, nullptr, so);
      if (std::string why = session.reachable(); !why.empty()) throw std::runtime_error(why);
      conf::map::ProbeLimits limits{discover_budget, discover_time, nullptr};
      conf::Progress progress("spec discover", discover_progress, discover_quiet);
      limits.on_request = [&](int sent, int budget) { progress.update(uint64_t(sent), uint64_t(budget), "requests"); };
      conf::map::Map m = conf::map::probe(session, limits);
      progress.clear();
      if (auto stop = session.stopped()) throw std::runtime_error("INCOMPLETE: " + *stop + "; no spec written");
      std::string id = discover_id.empty() ? fs::path(discover_out).stem().string() : discover_id;
      if (!write_file(discover_out, conf::map::skeleton_yaml(m, id, session.info().unit)))
        throw std::runtime_error("cannot write " + discover_out);
      std::cout << fmt::format("{}: {} ({} requests, {:.1f} s{})\n", discover_out, m.describe(), m.requests, m.seconds,
                               m.partial ? ", PARTIAL: the " + m.partial_by + " ran out at " + m.partial_at : "");
      for (const auto& d : m.deviations) std::cout << "DEVIATION: " << d << "\n";
      exit_code = kExitOk;
    } catch (const std::exception& e) {
      std::cerr << "mbconform spec discover: error: " << e.what() << "\n";
      exit_code = kExitUsage;
    }
  });

  auto* list = spec_cmd->add_subcommand("list", "List the device specs, each with its file and where it was found");
  list->callback([&] {
    auto files = spec::spec_files();
    size_t id_w = 0, path_w = 0;
    for (const auto& f : files) id_w = std::max(id_w, f.id.size()), path_w = std::max(path_w, f.path.size());
    for (const auto& f : files) std::cout << fmt::format("{:<{}}  {:<{}}  ({})\n", f.id, id_w, f.path, path_w, f.origin);
    exit_code = kExitOk;
  });
}

namespace {
void fall_through(CLI::App& app) {
  for (auto* sub : app.get_subcommands({})) {
    sub->fallthrough();
    fall_through(*sub);
  }
}
}  // namespace

void add_global_options(CLI::App& app) {
  app.add_option_function<std::vector<std::string>>(
         "--spec-dir",
         [](const std::vector<std::string>& dirs) {
           for (const auto& d : dirs) spec::add_spec_dir(d);
         },
         "a directory of your own device specs (DIR/devices/*.yaml or DIR/*.yaml); repeatable, searched before "
         "$MBCONFORM_SPEC_DIR and the specs that come with mbconform")
      ->type_name("DIR")
      ->allow_extra_args(false);
  fall_through(app);
}

}  // namespace mbc::cli
