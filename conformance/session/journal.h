// The write-ahead journal of a session (README.md, "Live drives: the
// journal"). Before the first write to any address of a live drive, the
// value that address held is appended here and the file is flushed to disk
// (fsync), so that whatever ends the command (SIGKILL, a crash, a power cut
// of the host) `mbconform restore JOURNAL` can put the drive back. What a
// restore did is appended to the same file.
//
// One line per record, in this order:
//   mbconform-journal 1
//   target <uri as opened>          device <spec id>          spec <spec file>
//   unit <N>                        command <run|props|...>   started <UTC>
//   orig <holding|coils> 0xADDR <words> <hex word>... [switch]
//   unread <holding|coils> 0xADDR <count> <why>
//   restored|verified|not-restored <table> 0xADDR [why]
//   end <restored|incomplete> ...
// The first `orig` of an address is its value before the command (a later
// one, from a forked child that journaled again, is ignored). `switch` marks
// the "do not persist" switch (57HS-R 0x0016): it goes back first.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "spec.h"

namespace mbc::conf {

struct JournalEntry {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  std::vector<uint16_t> value;  // in wire order (lower address first); bits as 0/1
  bool persist_switch = false;
  std::string name;             // for messages ("holding 0x0010 pulse/direction signal polarity")
};

struct JournalUnread {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  int count = 1;
  std::string why;
};

// The largest journal `read_journal` accepts (a journal holds at most one
// line per address of two tables).
inline constexpr size_t kMaxJournalBytes = 64u << 20;

class Journal {
 public:
  // Creates DIR/journal.txt (DIR is created), writes the header and fsyncs
  // it and the directory. Throws std::runtime_error naming the path.
  static Journal create(const std::string& dir, const std::map<std::string, std::string>& header);
  // Appends to an existing journal (mbconform restore).
  static Journal append_to(const std::string& path);
  Journal() = default;
  Journal(Journal&&) noexcept;
  Journal& operator=(Journal&&) noexcept;
  Journal(const Journal&) = delete;
  ~Journal();

  // Whether an item address of `table` already has its original journaled.
  bool has(spec::Table table, uint16_t address) const { return covered_.count({table, address}) > 0; }
  // Appends the originals (and unread items) and fsyncs before returning:
  // only then may the write go out. Throws std::runtime_error on I/O errors.
  void keep(const std::vector<JournalEntry>& originals, const std::vector<JournalUnread>& unread = {});
  // A line of the restore's record (fsync'd).
  void record(const std::string& line);
  const std::string& path() const { return path_; }
  bool open() const { return fd_ >= 0; }
  size_t kept() const { return kept_; }

 private:
  void write_line(const std::string& text);
  int fd_ = -1;
  std::string path_;
  std::set<std::pair<spec::Table, uint16_t>> covered_;
  size_t kept_ = 0;
};

struct JournalContents {
  std::map<std::string, std::string> header;
  std::vector<JournalEntry> originals;  // the first of each address, in journal order
  std::vector<JournalUnread> unread;
  std::vector<std::string> restore_lines;  // restored/verified/not-restored/end lines
  bool ended = false;                      // an `end` line came
};
// Reads a journal; std::runtime_error "PATH:LINE: ..." on a malformed line,
// a file over kMaxJournalBytes or one that is not a journal.
JournalContents read_journal(const std::string& path);

const char* journal_table_name(spec::Table);

}  // namespace mbc::conf
