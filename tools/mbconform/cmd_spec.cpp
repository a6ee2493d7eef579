// mbconform spec check | dump | errata | list
#include <filesystem>
#include <fstream>
#include <iostream>

#include <fmt/core.h>

#include "commands.h"
#include "dump.h"
#include "errata.h"
#include "loader.h"

namespace mbc::cli {
namespace {

namespace fs = std::filesystem;

int run_check(const std::vector<std::string>& files, bool quiet) {
  int failed = 0;
  for (const auto& f : files) {
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

int run_errata(std::vector<std::string> ids, const std::string& out_dir) {
  if (ids.empty()) ids = spec::spec_ids();
  spec::Spec standard = load_id_or_path("modbus-standard");
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  if (ec) throw std::runtime_error("cannot create " + out_dir + ": " + ec.message());
  for (const auto& id : ids) {
    spec::Spec s = load_id_or_path(id);
    auto report = spec::errata_report(s, standard);
    fs::path base = fs::path(out_dir) / s.device.id;
    if (!write_file(base.string() + ".json", report.dump(2) + "\n") ||
        !write_file(base.string() + ".md", spec::errata_markdown(report)))
      throw std::runtime_error("cannot write " + base.string() + ".{json,md}");
    const auto& sum = report["summary"];
    std::cout << fmt::format("{}.md: {} frames ({} bad CRC), {} errata, {} deviations\n", base.string(),
                             sum["frames"].get<int>(), sum["frames_bad_crc"].get<int>(), sum["errata"].get<int>(),
                             sum["deviations"].get<int>());
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
      for (const auto& id : spec::spec_ids()) files.push_back(spec::spec_path(id));
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

  auto* list = spec_cmd->add_subcommand("list", "List the device specs");
  list->callback([&] {
    for (const auto& id : spec::spec_ids()) std::cout << id << "\n";
    exit_code = kExitOk;
  });
}

}  // namespace mbc::cli
