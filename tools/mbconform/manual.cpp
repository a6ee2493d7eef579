// The man page (`mbconform help --man`) and the bash completion
// (`mbconform completion bash`), both written from the CLI11 definitions of
// the commands, so neither can drift from what the program takes: a new
// command or option is in both the moment it is added. The build writes them
// by running the built binary (cmake/Install.cmake), and they are installed
// with it; ctest `cli_manual` checks every command's `help` against both.
#include <fmt/core.h>

#include <algorithm>
#include <string>
#include <vector>

#include "commands.h"
#include "conventions.h"

namespace mbc::cli {
namespace {

// Every command that is shown (a command in a group; CLI11 hides the rest),
// depth first, as a path of names ("spec import").
struct Command {
  const CLI::App* app;
  std::string path;  // "" for the program itself
};

void walk(const CLI::App* app, const std::string& path, std::vector<Command>& out) {
  out.push_back({app, path});
  for (const CLI::App* sub : app->get_subcommands({}))
    if (!sub->get_group().empty()) walk(sub, path.empty() ? sub->get_name() : path + " " + sub->get_name(), out);
}

std::vector<Command> commands(const CLI::App& app) {
  std::vector<Command> out;
  walk(&app, "", out);
  return out;
}

// The options a command shows in its --help: not positionals, not hidden.
std::vector<const CLI::Option*> shown_options(const CLI::App* app) {
  std::vector<const CLI::Option*> out;
  for (const CLI::Option* o : app->get_options({}))
    if (o->nonpositional() && !o->get_group().empty()) out.push_back(o);
  return out;
}

std::vector<const CLI::Option*> positionals(const CLI::App* app) {
  std::vector<const CLI::Option*> out;
  for (const CLI::Option* o : app->get_options({}))
    if (!o->nonpositional()) out.push_back(o);
  return out;
}

bool takes_value(const CLI::Option* o) { return o->get_expected_max() != 0; }  // flags expect 0 values

std::vector<std::string> names_of(const CLI::Option* o) {
  std::vector<std::string> out;
  for (const auto& s : o->get_snames()) out.push_back("-" + s);
  for (const auto& l : o->get_lnames()) out.push_back("--" + l);
  return out;
}

// The options a command takes: its own, then those of the commands above it
// it falls through to (--spec-dir), without repeats (-h,--help).
std::vector<const CLI::Option*> options_taken(const CLI::App* app) {
  std::vector<const CLI::Option*> out;
  std::vector<std::string> seen;
  for (const CLI::App* a = app; a; a = a->get_fallthrough() ? a->get_parent() : nullptr)
    for (const CLI::Option* o : shown_options(a)) {
      auto names = names_of(o);
      if (std::any_of(names.begin(), names.end(), [&](const auto& n) { return std::count(seen.begin(), seen.end(), n); }))
        continue;
      seen.insert(seen.end(), names.begin(), names.end());
      out.push_back(o);
    }
  return out;
}

// roff: a backslash is \e, a hyphen \-, a line starting with . or ' is
// protected by \&.
std::string roff(const std::string& text) {
  std::string out;
  bool line_start = true;
  for (char c : text) {
    if (line_start && (c == '.' || c == '\'')) out += "\\&";
    if (c == '\\') out += "\\e";
    else if (c == '-') out += "\\-";
    else out += c;
    line_start = c == '\n';
  }
  return out;
}

std::string upper(std::string s) {
  for (char& c : s)
    if (c >= 'a' && c <= 'z') c = char(c - 'a' + 'A');
  return s;
}


std::string option_term(const CLI::Option* o) {
  std::string term;
  for (const auto& n : names_of(o)) term += (term.empty() ? "" : ", ") + ("\\fB" + roff(n) + "\\fR");
  if (takes_value(o) && !o->get_type_name().empty()) term += " \\fI" + roff(o->get_type_name()) + "\\fR";
  return term;
}

std::string usage(const Command& c) {
  std::string u = "mbconform" + (c.path.empty() ? "" : " " + c.path);
  if (!shown_options(c.app).empty()) u += " [OPTIONS]";
  for (const CLI::Option* p : positionals(c.app)) {
    std::string name = p->get_name();
    bool many = p->get_expected_max() > 1;
    u += " " + (p->get_required() ? name : "[" + name + "]") + (many ? "..." : "");
  }
  if (!c.app->get_subcommands({}).empty()) u += c.app->get_require_subcommand_min() > 0 ? " COMMAND" : " [COMMAND]";
  return u;
}

void options_section(std::string& out, const std::vector<const CLI::Option*>& opts) {
  for (const CLI::Option* o : opts) out += fmt::format(".TP\n{}\n{}\n", option_term(o), roff(o->get_description()));
}

}  // namespace

std::string man_page(const CLI::App& app) {
  std::vector<Command> all = commands(app);
  std::string out;
  out += fmt::format(".\\\" The mbconform man page, written by `mbconform help --man` from the commands' definitions.\n");
  out += fmt::format(".TH MBCONFORM 1 \"\" \"{}\" \"User Commands\"\n", kVersionLine);
  out += ".SH NAME\nmbconform \\- Modbus conformance and fuzz test suite for industrial motor drives\n";
  out += ".SH SYNOPSIS\n";
  out += ".B mbconform\n[\\fB\\-\\-spec\\-dir\\fR \\fIDIR\\fR]... \\fICOMMAND\\fR [\\fIOPTIONS\\fR]\n.br\n";
  out += ".B mbconform help\n[\\fICOMMAND\\fR...]\n.br\n.B mbconform \\-\\-version\n";
  out += ".SH DESCRIPTION\n";
  out += roff("mbconform checks Modbus devices, motor drives first, against a machine-readable spec of their manual "
              "and the Modbus standard: conformance cases, property tests and fuzzing against a live drive "
              "(serial RTU, Modbus TCP, RTU over TCP, Modbus/TCP Security), a vendor's stack as a plugin or the "
              "in-process reference devices; recorded captures judged without sending a frame; the reference devices "
              "served for other masters; a master library judged against scenario servers.") +
         "\n.PP\n" +
         roff("On a live drive nothing that moves it, wears its EEPROM, broadcasts or cannot be restored is sent "
              "without an opt-in (--allow-motion, --allow-eeprom-writes, --allow-broadcast, --allow-writes), and "
              "every value written is journaled first and restored at the end (mbconform restore JOURNAL after a "
              "crash). Run with --plan first to see every frame a run would send.") +
         "\n";
  out += ".SH COMMANDS\n";
  for (const Command& c : all)
    if (!c.path.empty()) out += fmt::format(".TP\n\\fB{}\\fR\n{}\n", roff(c.path), roff(c.app->get_description()));
  out += ".SH \"GLOBAL OPTIONS\"\n";
  options_section(out, shown_options(&app));
  for (const Command& c : all) {
    if (c.path.empty()) continue;
    out += fmt::format(".SH \"MBCONFORM {}\"\n", roff(upper(c.path)));
    out += fmt::format("{}\n.PP\n\\fB{}\\fR\n", roff(c.app->get_description()), roff(usage(c)));
    std::vector<const CLI::Option*> pos = positionals(c.app);
    if (!pos.empty()) {
      out += ".PP\nArguments:\n";
      for (const CLI::Option* p : pos) out += fmt::format(".TP\n\\fI{}\\fR\n{}\n", roff(p->get_name()), roff(p->get_description()));
    }
    std::vector<const CLI::Option*> own = shown_options(c.app);
    if (!own.empty()) {
      out += ".PP\nOptions:\n";
      options_section(out, own);
    }
    auto subs = c.app->get_subcommands({});
    if (!subs.empty()) {
      out += ".PP\nCommands:\n";
      for (const CLI::App* s : subs)
        if (!s->get_group().empty()) out += fmt::format(".TP\n\\fB{}\\fR\n{}\n", roff(s->get_name()), roff(s->get_description()));
    }
  }
  out += ".SH \"EXIT STATUS\"\n" + roff(exit_codes_footer()) + "\n";
  out += ".SH ENVIRONMENT\n";
  out += ".TP\n\\fBMBCONFORM_SPEC_DIR\\fR\n" +
         roff("Directories of device specs (colon-separated), searched after --spec-dir and before the specs that come "
              "with mbconform.") +
         "\n";
  out += ".TP\n\\fBMBCONFORM_PLUGIN_HOST\\fR\n" +
         roff("The plugin host for plugin: targets (default: mbconform-plugin-host beside mbconform).") + "\n";
  out += ".SH FILES\n";
  out += ".TP\n\\fIreports/COMMAND/YYYYMMDDTHHMMSSZ/\\fR\n" +
         roff("Where a command writes its reports (junit.xml, report.json, report.html) and its journal when no --out "
              "is given; a second run in the same second gets the same name with -2, -3, ...") +
         "\n";
  out += ".TP\n\\fI/usr/share/mbconform/devices/\\fR\n" + roff("The device specs that come with mbconform.") + "\n";
  out += ".TP\n\\fI/usr/share/mbconform/deviations/\\fR, \\fI/usr/share/mbconform/quirks/\\fR\n" +
         roff("The measured deviations of third-party Modbus libraries, as masters and as servers: --quirks NAME "
              "(e.g. --quirks libmodbus-tcp) finds NAME.yaml here.") +
         "\n";
  out += ".SH \"SEE ALSO\"\n" + roff("/usr/share/doc/mbconform/README.md, mbpoll(1), tshark(1)") + "\n";
  return out;
}

std::string bash_completion(const CLI::App& app) {
  std::vector<Command> all = commands(app);
  auto key = [](const std::string& path) {
    std::string k = path;
    std::replace(k.begin(), k.end(), ' ', '/');
    return k;
  };
  std::string subs_cases, opts_cases, valued_cases, paths;
  for (const Command& c : all) {
    std::string subs, opts, valued;
    for (const CLI::App* s : c.app->get_subcommands({}))
      if (!s->get_group().empty()) subs += (subs.empty() ? "" : " ") + s->get_name();
    for (const CLI::Option* o : options_taken(c.app))
      for (const auto& n : names_of(o)) {
        opts += (opts.empty() ? "" : " ") + n;
        if (takes_value(o)) valued += (valued.empty() ? "" : " ") + n;
      }
    std::string k = key(c.path);
    if (!c.path.empty()) paths += (paths.empty() ? "" : " ") + k;
    subs_cases += fmt::format("    '{}') words='{}' ;;\n", k, subs);
    opts_cases += fmt::format("    '{}') words='{}' ;;\n", k, opts);
    valued_cases += fmt::format("    '{}') words='{}' ;;\n", k, valued);
  }
  std::string top;
  for (const CLI::App* s : app.get_subcommands({}))
    if (!s->get_group().empty()) top += (top.empty() ? "" : " ") + s->get_name();
  return fmt::format(R"SH(# bash completion for mbconform ({version}); written by `mbconform completion bash`
# from the commands' definitions: do not edit, regenerate.
_mbconform_subcommands() {{
  local words=''
  case "$1" in
{subs}  esac
  echo "$words"
}}
_mbconform_options() {{
  local words=''
  case "$1" in
{opts}  esac
  echo "$words"
}}
_mbconform_valued() {{
  local words=''
  case "$1" in
{valued}  esac
  echo "$words"
}}
_mbconform() {{
  local cur=${{COMP_WORDS[COMP_CWORD]}} prev='' path='' w i
  local paths=' {paths} '
  for ((i = 1; i < COMP_CWORD; i++)); do
    w=${{COMP_WORDS[i]}}
    if [[ $w == -* ]]; then
      # An option that takes a value: the next word is its value, not a command.
      [[ $w != *=* && " $(_mbconform_valued "$path") " == *" $w "* ]] && ((i++))
      continue
    fi
    [[ $paths == *" ${{path:+$path/}}$w "* ]] && path=${{path:+$path/}}$w
  done
  ((COMP_CWORD > 1)) && prev=${{COMP_WORDS[COMP_CWORD - 1]}}
  if [[ $prev == -* && " $(_mbconform_valued "$path") " == *" $prev "* ]]; then
    case "$prev" in
      --device)
        COMPREPLY=($(compgen -W "$("${{COMP_WORDS[0]}}" spec list 2>/dev/null | cut -d' ' -f1)" -- "$cur")) ;;
      *) compopt -o default 2>/dev/null; COMPREPLY=() ;;
    esac
    return
  fi
  if [[ $cur == -* ]]; then
    COMPREPLY=($(compgen -W "$(_mbconform_options "$path")" -- "$cur"))
    return
  fi
  case "$path" in
    help) COMPREPLY=($(compgen -W '{top}' -- "$cur")); return ;;
    completion) COMPREPLY=($(compgen -W 'bash' -- "$cur")); return ;;
  esac
  local subs
  subs=$(_mbconform_subcommands "$path")
  if [[ -n $subs ]]; then
    COMPREPLY=($(compgen -W "$subs" -- "$cur"))
  else
    compopt -o default 2>/dev/null
    COMPREPLY=()
  fi
}}
complete -F _mbconform mbconform
)SH",
                     fmt::arg("version", kVersionLine), fmt::arg("subs", subs_cases), fmt::arg("opts", opts_cases),
                     fmt::arg("valued", valued_cases), fmt::arg("paths", paths), fmt::arg("top", top));
}

void add_completion_command(CLI::App& app, int& exit_code) {
  auto* completion = app.add_subcommand("completion", "Print the shell completion script (bash: source <(mbconform completion bash))");
  static std::string shell = "bash";
  completion->add_option("shell", shell, "the shell: bash")->check(CLI::IsMember({"bash"}))->capture_default_str();
  completion->callback([&app, &exit_code] {
    std::fputs(bash_completion(app).c_str(), stdout);
    exit_code = kExitOk;
  });
}

}  // namespace mbc::cli
