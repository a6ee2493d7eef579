#include "conventions.h"

#include <fmt/chrono.h>
#include <fmt/core.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <ctime>

#include "report/report.h"
#include "report/utc_now.h"

namespace mbc::cli {

std::string default_out_dir(const std::string& command) {
  return conf::claim_new_dir("reports/" + command, conf::utc_now("%Y%m%dT%H%M%SZ"));
}

std::optional<std::chrono::milliseconds> parse_duration(const std::string& text, std::chrono::milliseconds min,
                                                        std::chrono::milliseconds max) {
  size_t used = 0;
  double v = 0;
  if (text.empty() || std::isspace(static_cast<unsigned char>(text.front()))) return std::nullopt;
  try {
    v = std::stod(text, &used);
  } catch (...) {
    return std::nullopt;
  }
  std::string unit = text.substr(used);
  double scale = unit == "ms" ? 1 : unit == "" || unit == "s" ? 1e3 : unit == "m" ? 60e3 : unit == "h" ? 3600e3 : -1;
  double ms = v * scale;
  // NaN and infinities fail both comparisons; the range check comes before
  // the conversion, so no value overflows.
  if (scale < 0 || !(ms >= double(min.count())) || !(ms <= double(max.count()))) return std::nullopt;
  return std::chrono::milliseconds(int64_t(ms));
}

namespace {

std::string duration_text(std::chrono::milliseconds d) {
  auto ms = d.count();
  if (ms % (24 * 3600000) == 0) return fmt::format("{} days", ms / (24 * 3600000));
  if (ms % 3600000 == 0) return fmt::format("{} h", ms / 3600000);
  if (ms % 1000 == 0) return fmt::format("{} s", ms / 1000);
  return fmt::format("{} ms", ms);
}

}  // namespace

std::string duration_error(const std::string& option, const std::string& text, std::chrono::milliseconds min,
                           std::chrono::milliseconds max) {
  return fmt::format("{} '{}': expected a duration from {} to {}, e.g. 500ms, 90s, 10m, 2h", option, text,
                     duration_text(min), duration_text(max));
}

void add_map_time_option(CLI::App* cmd, std::optional<std::chrono::milliseconds>& into) {
  cmd->add_option_function<std::string>(
         "--map-time",
         [&into](const std::string& text) {
           auto d = parse_duration(text);
           if (!d) throw CLI::ValidationError(duration_error("--map-time", text));
           into = *d;
         },
         "the longest the map probe runs (e.g. 90s, 2m); default: until --map-budget runs out")
      ->type_name("DURATION");
}

void add_fail_on_option(CLI::App* cmd, bool& fail_on_should) {
  cmd->add_option_function<std::string>(
         "--fail-on", [&fail_on_should](const std::string& level) { fail_on_should = level == "should"; },
         "must (default): only a failed MUST fails the run; should: a failed SHOULD does too (exit 1, JUnit <failure>)")
      ->check(CLI::IsMember({"must", "should"}))
      ->type_name("LEVEL");
}

bool run_failed(const conf::RunReport& report) {
  for (const auto& d : report.devices)
    for (const auto& r : d.cases)
      if (conf::fails_run(r, report)) return true;
  return false;
}

const char* exit_codes_footer() {
  return "Exit codes: 0 success (PASS, or PARTIAL: MUST cases skipped for want of an opt-in, named); 1 the check failed "
         "(spec errors, a failing MUST case, a falsified property, a fuzz finding); 2 the command could not run (bad "
         "arguments, bad target, bad spec, unreadable files, interrupted, a lost target); 3 PARTIAL under "
         "--require-complete.";
}

namespace {
// Optimal string alignment distance: a transposition ("devcie") is one edit.
size_t distance(const std::string& a, const std::string& b) {
  std::vector<std::vector<size_t>> d(a.size() + 1, std::vector<size_t>(b.size() + 1));
  for (size_t i = 0; i <= a.size(); ++i) d[i][0] = i;
  for (size_t j = 0; j <= b.size(); ++j) d[0][j] = j;
  for (size_t i = 1; i <= a.size(); ++i)
    for (size_t j = 1; j <= b.size(); ++j) {
      d[i][j] = std::min({d[i - 1][j] + 1, d[i][j - 1] + 1, d[i - 1][j - 1] + (a[i - 1] == b[j - 1] ? 0 : 1)});
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1]) d[i][j] = std::min(d[i][j], d[i - 2][j - 2] + 1);
    }
  return d[a.size()][b.size()];
}
}  // namespace

namespace {

void footer_everywhere(CLI::App* app) {
  app->footer(exit_codes_footer());
  for (auto* sub : app->get_subcommands({})) footer_everywhere(sub);
}

std::vector<std::string> subcommand_names(const CLI::App* app) {
  std::vector<std::string> out;
  for (const auto* sub : app->get_subcommands({})) out.push_back(sub->get_name());
  return out;
}

// The long names of the options `app` and its parents take.
std::vector<std::string> option_names(const CLI::App* app) {
  std::vector<std::string> out;
  for (const CLI::App* a = app; a; a = a->get_parent())
    for (const auto* o : a->get_options({})) {
      for (const auto& l : o->get_lnames()) out.push_back("--" + l);
      for (const auto& s : o->get_snames()) out.push_back("-" + s);
    }
  return out;
}

bool takes(const CLI::App* app, const std::string& name) {
  auto names = option_names(app);
  return std::find(names.begin(), names.end(), name) != names.end();
}

std::string path_of(const CLI::App* app) {
  std::string p;
  for (const CLI::App* a = app; a && a->get_parent(); a = a->get_parent()) p = a->get_name() + (p.empty() ? "" : " " + p);
  return "mbconform" + (p.empty() ? "" : " " + p);
}

}  // namespace

void add_conventions(CLI::App& app, int& exit_code) {
  app.set_version_flag("--version", kVersionLine);
  auto* help = app.add_subcommand("help", "Print the help of a command (mbconform help run; mbconform help spec import)");
  static std::vector<std::string> topic;
  static bool man = false;
  help->add_option("command", topic, "the command (and subcommand)");
  help->add_flag("--man", man, "print the man page instead (roff; read it with: mbconform help --man | man -l -)");
  add_completion_command(app, exit_code);
  help->callback([&app, &exit_code] {
    if (man) {
      std::fputs(man_page(app).c_str(), stdout);
      exit_code = 0;
      return;
    }
    CLI::App* at = &app;
    for (const auto& word : topic) {
      CLI::App* next = nullptr;
      for (auto* sub : at->get_subcommands({}))
        if (sub->get_name() == word) next = sub;
      if (!next) {
        std::string near = nearest(word, subcommand_names(at));
        std::fprintf(stderr, "%s: error: unknown command '%s'%s\n", path_of(at).c_str(), word.c_str(),
                     near.empty() ? "" : ("; did you mean '" + near + "'?").c_str());
        exit_code = 2;
        return;
      }
      at = next;
    }
    // The formatter itself: App::help() would show `help`'s own help (the
    // command running now); the usage line names the whole path.
    std::string text = at->get_formatter()->make_help(at, path_of(at), CLI::AppFormatMode::Normal);
    if (!text.empty() && text.back() != '\n') text += '\n';
    std::printf("%s", text.c_str());
    exit_code = 0;
  });
  footer_everywhere(&app);
}

std::optional<int> check_args(CLI::App& app, std::vector<std::string>& args, std::string* command) {
  // Walk the words: commands down the tree, options of the command reached.
  CLI::App* at = &app;
  struct Named {
    std::string* into;
    CLI::App*& at;
    ~Named() {
      if (into) *into = path_of(at);
    }
  } named{command, at};
  bool positional_seen = false;
  for (size_t i = 0; i < args.size(); ++i) {
    std::string& w = args[i];
    if (w == "--") break;
    if (w.rfind("--", 0) == 0 || (w.size() == 2 && w[0] == '-' && std::isalpha(static_cast<unsigned char>(w[1])))) {
      std::string name = w.substr(0, w.find('='));
      if (name == "--help" || name == "-h" || name == "--version") continue;
      if (name == "-q" && !takes(at, "-q") && takes(at, "--quiet")) {
        w = "--quiet";
        continue;
      }
      if (name == "-v" && !takes(at, "-v") && takes(at, "--verbose")) {
        w = "--verbose";
        continue;
      }
      if (!takes(at, name)) {
        std::string near = nearest(name, option_names(at));
        std::fprintf(stderr, "%s: error: unknown option '%s'%s (%s --help lists them)\n", path_of(at).c_str(), name.c_str(),
                     near.empty() ? "" : ("; did you mean '" + near + "'?").c_str(), path_of(at).c_str());
        return 2;
      }
      // An option's value is not a command: skip it when the option takes one.
      const CLI::Option* opt = nullptr;
      for (const CLI::App* a = at; a && !opt; a = a->get_parent()) opt = a->get_option_no_throw(name);
      if (opt && opt->get_expected_max() != 0 && w.find('=') == std::string::npos) ++i;
      continue;
    }
    if (positional_seen) continue;
    auto subs = at->get_subcommands({});
    CLI::App* next = nullptr;
    for (auto* sub : subs)
      if (sub->get_name() == w) next = sub;
    if (next) {
      at = next;
      continue;
    }
    if (!subs.empty() && at->get_require_subcommand_min() > 0) {
      std::string near = nearest(w, subcommand_names(at));
      std::fprintf(stderr, "%s: error: unknown command '%s'%s (%s --help lists them)\n", path_of(at).c_str(), w.c_str(),
                   near.empty() ? "" : ("; did you mean '" + near + "'?").c_str(), path_of(at).c_str());
      return 2;
    }
    positional_seen = true;  // the command's own arguments (spec check FILE...)
  }
  return std::nullopt;
}

std::string nearest(const std::string& word, const std::vector<std::string>& known) {
  std::string best;
  size_t best_d = 3;
  for (const auto& k : known) {
    size_t d = distance(word, k);
    if (d < best_d) {
      best_d = d;
      best = k;
    }
  }
  return best;
}

}  // namespace mbc::cli
