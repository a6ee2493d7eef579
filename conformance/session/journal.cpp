#include "session/journal.h"

#include <fcntl.h>
#include <fmt/core.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace mbc::conf {
namespace {

constexpr const char* kMagic = "mbconform-journal 2";
constexpr const char* kMagicV1 = "mbconform-journal 1";
constexpr const char* kHeaderKeys[] = {"target", "device", "spec", "spec-crc32", "unit", "command", "started"};

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

std::optional<unsigned> number(std::string_view v, int base) {
  if (base == 16 && v.rfind("0x", 0) == 0) v.remove_prefix(2);
  unsigned n = 0;
  auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), n, base);
  if (ec != std::errc{} || end != v.data() + v.size() || v.empty()) return std::nullopt;
  return n;
}

// A journaled word is always 4 hex digits: "00" is a word cut short, not 0x0000.
std::optional<uint16_t> word(const std::string& s) {
  if (s.size() != 4) return std::nullopt;
  auto v = number(s, 16);
  if (!v) return std::nullopt;
  return uint16_t(*v);
}

std::string one_line(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  return s;
}

std::string words_text(const std::vector<uint16_t>& value) {
  std::string s = std::to_string(value.size());
  for (uint16_t w : value) s += fmt::format(" {:04X}", w);
  return s;
}

// "TABLE 0xADDR COUNT" at the start of `ls`; nullopt when malformed.
struct Where {
  spec::Table table;
  uint16_t address;
  unsigned count;
};
std::optional<Where> where(std::istringstream& ls) {
  std::string table, addr, count;
  ls >> table >> addr >> count;
  auto t = table_of(table);
  auto a = number(addr, 16);
  auto k = number(count, 10);
  if (!t || !a || *a > 0xFFFF || !k || *k == 0 || *k > 2000) return std::nullopt;
  return Where{*t, uint16_t(*a), *k};
}

std::optional<std::vector<uint16_t>> words(std::istringstream& ls, unsigned n) {
  std::vector<uint16_t> out;
  for (unsigned i = 0; i < n; ++i) {
    std::string w;
    ls >> w;
    auto v = word(w);
    if (!v) return std::nullopt;
    out.push_back(*v);
  }
  return out;
}

std::string rest_of(std::istringstream& ls) {
  std::string v;
  std::getline(ls, v);
  return v.empty() ? v : v.substr(1);
}

}  // namespace

uint32_t journal_crc32(std::string_view bytes) {
  static const auto table = [] {
    std::array<uint32_t, 256> t{};
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = c & 1 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  uint32_t c = 0xFFFFFFFFu;
  for (unsigned char b : bytes) c = table[(c ^ b) & 0xFF] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

std::string journal_line(const std::string& text) { return fmt::format("{} *{:08X}", text, journal_crc32(text)); }

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
  if (j.fd_ < 0)
    throw std::runtime_error(fmt::format("journal {}: cannot create: {}", j.path_, std::strerror(errno)));
  std::string text = std::string(kMagic) + "\n";
  for (const char* key : kHeaderKeys)
    if (auto it = header.find(key); it != header.end()) {
      text += journal_line(fmt::format("{} {}", key, one_line(it->second))) + "\n";
      j.memory_.header[key] = one_line(it->second);
    }
  size_t at = 0;
  while (at < text.size()) {
    ssize_t n = ::write(j.fd_, text.data() + at, text.size() - at);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw std::runtime_error(fmt::format("journal {}: cannot write: {}", j.path_, std::strerror(errno)));
    at += size_t(n);
  }
  if (::fdatasync(j.fd_) != 0)
    throw std::runtime_error(fmt::format("journal {}: cannot flush to disk: {}", j.path_, std::strerror(errno)));
  fsync_dir(dir);
  return j;
}

Journal Journal::append_to(const std::string& path) {
  Journal j;
  j.path_ = path;
  j.fd_ = ::open(path.c_str(), O_RDWR | O_APPEND | O_CLOEXEC);
  if (j.fd_ < 0) throw std::runtime_error(fmt::format("journal {}: cannot append: {}", path, std::strerror(errno)));
  // A journal whose last line was cut off: the next record starts on a line of its own.
  char last = '\n';
  if (off_t size = ::lseek(j.fd_, 0, SEEK_END); size > 0 && ::pread(j.fd_, &last, 1, size - 1) == 1) j.partial_ = last != '\n';
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
    failed_ = std::move(o.failed_);
    partial_ = o.partial_;
    memory_ = std::move(o.memory_);
  }
  return *this;
}
Journal::~Journal() {
  if (fd_ >= 0) ::close(fd_);
}

void Journal::write_records(const std::vector<std::string>& lines) {
  if (fd_ < 0) throw std::runtime_error("journal: not open");
  std::string text = partial_ ? "\n" : "";
  for (const auto& l : lines) text += journal_line(l) + "\n";
  size_t at = 0;
  while (at < text.size()) {
    ssize_t n = ::write(fd_, text.data() + at, text.size() - at);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : ENOSPC;
      partial_ = partial_ || at > 0;
      failed_ = fmt::format("cannot write {}: {}", path_, std::strerror(err));
      throw std::runtime_error("journal " + failed_);
    }
    at += size_t(n);
    partial_ = text[at - 1] != '\n';
  }
  if (::fdatasync(fd_) != 0) {
    failed_ = fmt::format("cannot flush {} to disk: {}", path_, std::strerror(errno));
    throw std::runtime_error("journal " + failed_);
  }
}

void Journal::keep(const std::vector<JournalEntry>& originals, const std::vector<JournalUnread>& unread,
                   const std::vector<JournalCommand>& commands) {
  std::vector<std::string> lines;
  for (const auto& e : originals) {
    if (has(e.table, e.address)) continue;
    lines.push_back(fmt::format("orig {} 0x{:04X} {}{}", journal_table_name(e.table), e.address, words_text(e.value),
                                e.persist_switch ? " switch" : ""));
    memory_.originals.push_back(e);
  }
  for (const auto& u : unread) {
    if (has(u.table, u.address)) continue;
    lines.push_back(fmt::format("unread {} 0x{:04X} {} {}", journal_table_name(u.table), u.address, u.count, one_line(u.why)));
    memory_.unread.push_back(u);
  }
  for (const auto& c : commands) {
    if (has(c.table, c.address)) continue;
    lines.push_back(fmt::format("cmd {} 0x{:04X} {}", journal_table_name(c.table), c.address, c.count));
    memory_.commands.push_back(c);
  }
  if (lines.empty()) return;
  write_records(lines);
  // Only now, on disk, do they count as kept.
  for (const auto& e : originals)
    for (size_t k = 0; k < e.value.size(); ++k)
      if (covered_.insert({e.table, uint16_t(e.address + k)}).second && k == 0) ++kept_;
  for (const auto& u : unread)
    for (int k = 0; k < u.count; ++k) covered_.insert({u.table, uint16_t(u.address + k)});
  for (const auto& c : commands)
    for (int k = 0; k < c.count; ++k)
      if (covered_.insert({c.table, uint16_t(c.address + k)}).second && k == 0) ++kept_;
}

void Journal::record(const std::string& line) {
  std::istringstream ls(line);
  std::string kind;
  ls >> kind;
  if (kind == "identity") memory_.header["identity"] = rest_of(ls);
  if (kind == "control" && memory_.control_state.empty()) {
    ls >> memory_.control_state;
    memory_.control_status = rest_of(ls);
  }
  write_records({one_line(line)});
}

bool Journal::try_record(const std::string& line) {
  try {
    record(line);
    return true;
  } catch (const std::exception&) {
    return false;
  }
}

JournalContents read_journal(const std::string& path) {
  std::error_code ec;
  auto st = std::filesystem::status(path, ec);
  if (ec || !std::filesystem::exists(st)) throw std::runtime_error(fmt::format("{}: no such file", path));
  if (!std::filesystem::is_regular_file(st)) throw std::runtime_error(fmt::format("{}: not a regular file: not a journal", path));
  auto size = std::filesystem::file_size(path, ec);
  if (ec) throw std::runtime_error(fmt::format("{}: cannot read: {}", path, ec.message()));
  if (size > kMaxJournalBytes)
    throw std::runtime_error(fmt::format("{}: {} bytes, more than a journal holds ({} at most)", path, size, kMaxJournalBytes));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("{}: cannot open", path));
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (all.empty()) throw std::runtime_error(fmt::format("{}: empty: not an mbconform journal", path));

  JournalContents c;
  std::set<std::pair<spec::Table, uint16_t>> seen;
  int n = 0;
  size_t at = 0;
  while (at < all.size()) {
    size_t nl = all.find('\n', at);
    const bool complete = nl != std::string::npos;
    std::string line = all.substr(at, complete ? nl - at : std::string::npos);
    at = complete ? nl + 1 : all.size();
    ++n;
    const bool last = at >= all.size();
    if (n == 1) {
      if (line == kMagicV1) c.format = 1;
      else if (line != kMagic)
        throw std::runtime_error(fmt::format("{}:1: error: not an mbconform journal (the first line is '{}')", path, kMagic));
      continue;
    }
    if (line.empty()) continue;
    auto torn = [&](const std::string& why) { c.torn.push_back({n, last, why}); };
    std::string text = line;
    if (c.format >= 2) {
      auto star = line.rfind(" *");
      auto sum = star == std::string::npos ? std::nullopt : number(std::string_view(line).substr(star + 2), 16);
      if (!sum || line.size() - star - 2 != 8) {
        torn(complete ? "no checksum" : "cut off (no checksum, no end of line)");
        continue;
      }
      text = line.substr(0, star);
      if (journal_crc32(text) != *sum) {
        torn("checksum does not match");
        continue;
      }
    } else if (!complete) {
      torn("cut off (no end of line)");
      continue;
    }
    std::istringstream ls(text);
    std::string kind;
    ls >> kind;
    if (kind == "orig") {
      auto w = where(ls);
      auto v = w ? words(ls, w->count) : std::nullopt;
      if (!v) {
        torn("an orig record without TABLE 0xADDR COUNT and that many 4-digit hex words");
        continue;
      }
      JournalEntry e{w->table, w->address, *v, false, ""};
      std::string flag;
      if (ls >> flag) {
        if (flag != "switch") {
          torn("unknown flag '" + flag + "'");
          continue;
        }
        e.persist_switch = true;
      }
      if (!seen.insert({e.table, e.address}).second) continue;  // the first value is the original
      c.originals.push_back(std::move(e));
    } else if (kind == "unread" || kind == "cmd") {
      auto w = where(ls);
      if (!w) {
        torn("expected TABLE 0xADDR COUNT");
        continue;
      }
      if (kind == "unread") c.unread.push_back({w->table, w->address, int(w->count), rest_of(ls)});
      else c.commands.push_back({w->table, w->address, int(w->count)});
    } else if (kind == "restored" || kind == "verified") {
      c.restore_lines.push_back(text);
      std::istringstream again(text);
      again >> kind;
      // Format 1 records no value: the address is only named.
      if (auto w = where(again))
        if (auto v = words(again, w->count)) {
          JournalRestored r{w->table, w->address, *v};
          bool replaced = false;
          for (auto& old : c.restored)
            if (old.table == r.table && old.address == r.address) old = r, replaced = true;
          if (!replaced) c.restored.push_back(std::move(r));
        }
    } else if (kind == "not-restored" || kind == "left" || kind == "restore" || kind == "stopped") {
      c.restore_lines.push_back(text);
    } else if (kind == "control") {
      std::string state;
      if (!(ls >> state)) {
        torn("a control record without a state");
        continue;
      }
      if (c.control_state.empty()) {
        c.control_state = state;
        c.control_status = rest_of(ls);
      }
    } else if (kind == "end") {
      c.restore_lines.push_back(text);
      c.ended = true;
    } else if (kind == "identity" || std::find(std::begin(kHeaderKeys), std::end(kHeaderKeys), kind) != std::end(kHeaderKeys)) {
      c.header[kind] = rest_of(ls);
    } else {
      torn("unknown record '" + kind + "'");
    }
  }
  return c;
}

JournalContents merge_journal(JournalContents disk, const JournalContents& memory) {
  auto has = [](const auto& list, spec::Table t, uint16_t a) {
    for (const auto& x : list)
      if (x.table == t && x.address == a) return true;
    return false;
  };
  for (const auto& e : memory.originals)
    if (!has(disk.originals, e.table, e.address)) disk.originals.push_back(e);
  for (const auto& u : memory.unread)
    if (!has(disk.unread, u.table, u.address)) disk.unread.push_back(u);
  for (const auto& k : memory.commands)
    if (!has(disk.commands, k.table, k.address)) disk.commands.push_back(k);
  for (const auto& [key, value] : memory.header) disk.header.emplace(key, value);
  if (disk.control_state.empty()) {
    disk.control_state = memory.control_state;
    disk.control_status = memory.control_status;
  }
  return disk;
}

}  // namespace mbc::conf
