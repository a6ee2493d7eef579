#include "session/journal.h"

#include <fcntl.h>
#include <fmt/core.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace mbc::conf {
namespace {

constexpr const char* kMagic = "mbconform-journal 1";

std::runtime_error io_error(const std::string& path, const char* what) {
  return std::runtime_error(fmt::format("journal {}: {}: {}", path, what, std::strerror(errno)));
}

void fsync_dir(const std::string& dir) {
  int fd = ::open(dir.empty() ? "." : dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  (void)::fsync(fd);
  ::close(fd);
}

std::optional<spec::Table> table_of(const std::string& name) {
  if (name == "holding") return spec::Table::holding;
  if (name == "coils") return spec::Table::coil;
  return std::nullopt;
}

std::optional<unsigned> number(const std::string& s, int base) {
  std::string_view v = s;
  if (base == 16 && v.rfind("0x", 0) == 0) v.remove_prefix(2);
  unsigned n = 0;
  auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), n, base);
  if (ec != std::errc{} || end != v.data() + v.size() || v.empty()) return std::nullopt;
  return n;
}

}  // namespace

const char* journal_table_name(spec::Table t) {
  switch (t) {
    case spec::Table::holding: return "holding";
    case spec::Table::coil: return "coils";
    case spec::Table::input: return "input";
    case spec::Table::discrete_input: return "discrete";
  }
  return "holding";
}

Journal Journal::create(const std::string& dir, const std::map<std::string, std::string>& header) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  Journal j;
  j.path_ = (std::filesystem::path(dir) / "journal.txt").string();
  // A journal left by an earlier command in the same directory is kept: it
  // may be all that can put a drive back.
  if (std::filesystem::exists(j.path_)) {
    for (int i = 1;; ++i) {
      std::string p = (std::filesystem::path(dir) / fmt::format("journal-{}.txt", i)).string();
      if (!std::filesystem::exists(p)) {
        j.path_ = p;
        break;
      }
    }
  }
  j.fd_ = ::open(j.path_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_APPEND | O_CLOEXEC, 0644);
  if (j.fd_ < 0) throw io_error(j.path_, "cannot create");
  std::string text = std::string(kMagic) + "\n";
  for (const char* key : {"target", "device", "spec", "unit", "command", "started"})
    if (auto it = header.find(key); it != header.end()) text += fmt::format("{} {}\n", key, it->second);
  j.write_line(text.substr(0, text.size() - 1));
  fsync_dir(dir);
  return j;
}

Journal Journal::append_to(const std::string& path) {
  Journal j;
  j.path_ = path;
  j.fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
  if (j.fd_ < 0) throw io_error(path, "cannot append");
  return j;
}

Journal::Journal(Journal&& o) noexcept { *this = std::move(o); }
Journal& Journal::operator=(Journal&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(o.fd_, -1);
    path_ = std::move(o.path_);
    covered_ = std::move(o.covered_);
    kept_ = o.kept_;
  }
  return *this;
}
Journal::~Journal() {
  if (fd_ >= 0) ::close(fd_);
}

void Journal::write_line(const std::string& text) {
  if (fd_ < 0) throw std::runtime_error("journal: not open");
  std::string line = text + "\n";
  size_t at = 0;
  while (at < line.size()) {
    ssize_t n = ::write(fd_, line.data() + at, line.size() - at);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw io_error(path_, "cannot write");
    at += size_t(n);
  }
  if (::fdatasync(fd_) != 0) throw io_error(path_, "cannot flush to disk");
}

void Journal::keep(const std::vector<JournalEntry>& originals, const std::vector<JournalUnread>& unread) {
  std::string text;
  for (const auto& e : originals) {
    if (has(e.table, e.address)) continue;
    text += fmt::format("orig {} 0x{:04X} {}", journal_table_name(e.table), e.address, e.value.size());
    for (uint16_t w : e.value) text += fmt::format(" {:04X}", w);
    if (e.persist_switch) text += " switch";
    text += "\n";
  }
  for (const auto& u : unread) {
    if (has(u.table, u.address)) continue;
    std::string why = u.why;
    for (char& c : why)
      if (c == '\n') c = ' ';
    text += fmt::format("unread {} 0x{:04X} {} {}\n", journal_table_name(u.table), u.address, u.count, why);
  }
  if (text.empty()) return;
  text.pop_back();
  write_line(text);
  // Only now, on disk, do they count as kept.
  for (const auto& e : originals)
    for (size_t k = 0; k < e.value.size(); ++k)
      if (covered_.insert({e.table, uint16_t(e.address + k)}).second && k == 0) ++kept_;
  for (const auto& u : unread)
    for (int k = 0; k < u.count; ++k) covered_.insert({u.table, uint16_t(u.address + k)});
}

void Journal::record(const std::string& line) { write_line(line); }

JournalContents read_journal(const std::string& path) {
  std::error_code ec;
  auto size = std::filesystem::file_size(path, ec);
  if (ec) throw std::runtime_error(fmt::format("{}: cannot read: {}", path, ec.message()));
  if (size > kMaxJournalBytes)
    throw std::runtime_error(fmt::format("{}: {} bytes, more than a journal holds ({} at most)", path, size, kMaxJournalBytes));
  std::ifstream in(path);
  if (!in) throw std::runtime_error(fmt::format("{}: cannot open", path));
  JournalContents c;
  std::set<std::pair<spec::Table, uint16_t>> seen;
  std::string line;
  int n = 0;
  auto bad = [&](const std::string& why) {
    return std::runtime_error(fmt::format("{}:{}: error: {}: {}", path, n, why, line));
  };
  size_t read = 0;
  while (std::getline(in, line)) {
    ++n;
    read += line.size() + 1;
    if (read > kMaxJournalBytes) throw bad("journal too long");
    if (n == 1) {
      if (line != kMagic) throw bad("not an mbconform journal (the first line is '" + std::string(kMagic) + "')");
      continue;
    }
    if (line.empty()) continue;
    std::istringstream ls(line);
    std::string kind;
    ls >> kind;
    if (kind == "orig" || kind == "unread") {
      std::string table, addr, count;
      ls >> table >> addr >> count;
      auto t = table_of(table);
      auto a = number(addr, 16);
      auto k = number(count, 10);
      if (!t || !a || *a > 0xFFFF || !k || *k == 0 || *k > 2000) throw bad("expected TABLE 0xADDR COUNT");
      if (kind == "unread") {
        std::string why;
        std::getline(ls, why);
        c.unread.push_back({*t, uint16_t(*a), int(*k), why.empty() ? why : why.substr(1)});
        continue;
      }
      JournalEntry e{*t, uint16_t(*a), {}, false, ""};
      for (unsigned i = 0; i < *k; ++i) {
        std::string w;
        ls >> w;
        auto v = number(w, 16);
        if (!v || *v > 0xFFFF) throw bad("expected a hex word");
        e.value.push_back(uint16_t(*v));
      }
      std::string flag;
      if (ls >> flag) {
        if (flag != "switch") throw bad("unknown flag '" + flag + "'");
        e.persist_switch = true;
      }
      if (!seen.insert({e.table, e.address}).second) continue;  // the first value is the original
      c.originals.push_back(std::move(e));
    } else if (kind == "restored" || kind == "verified" || kind == "not-restored" || kind == "restore") {
      c.restore_lines.push_back(line);
    } else if (kind == "end") {
      c.restore_lines.push_back(line);
      c.ended = true;
    } else if (kind == "target" || kind == "device" || kind == "spec" || kind == "unit" || kind == "command" ||
               kind == "started") {
      std::string v;
      std::getline(ls, v);
      c.header[kind] = v.empty() ? v : v.substr(1);
    } else {
      throw bad("unknown record '" + kind + "'");
    }
  }
  if (n == 0) throw std::runtime_error(fmt::format("{}: empty: not an mbconform journal", path));
  return c;
}

}  // namespace mbc::conf
