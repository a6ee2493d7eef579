// The write-ahead journal of a session (session/README.md has the format and
// the rules). Before the first write to any address of a live drive, the
// value that address held is appended here and the file is flushed to disk
// (fdatasync), so that whatever ends the command (SIGKILL, a crash, a power
// cut of the host) `mbconform restore JOURNAL` can put the drive back. What a
// restore did is appended to the same file, with the values it wrote.
//
// One record a line, each ending in ` *CRC` (CRC-32 of the text before it,
// 8 hex digits): a line cut short by a crash or a full disk, or damaged
// later, fails its checksum and is named and skipped, never read as a value.
//   mbconform-journal 2
//   target <uri> | device <id> | spec <file> | spec-crc32 <hex> | unit <N> | command <name> | started <UTC>
//   identity <what the drive answered to the identity reads>
//   orig <holding|coils> 0xADDR <words> <hex word>... [switch]
//   unread <holding|coils> 0xADDR <count> <why>
//   cmd <holding|coils> 0xADDR <count>        a command register written: undone by the spec's stop
//   restored|verified <table> 0xADDR <words> <hex word>... [why]
//   not-restored|left <table> 0xADDR [why]
//   stopped <how>
//   control <state id> <status key>=<hex word>...   the control state before the first command write
//   end <restored|incomplete> ...
// The first `orig` of an address is its value before the command (a later
// one, from a forked child that journaled again, is ignored). `switch` marks
// the "do not persist" switch (57HS-R 0x0016): it goes back first. Journals
// of format 1 (no checksums) are still read.
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

// A command register written (`access: command`): no value to put back; its
// effect is undone by the spec's stop operation.
struct JournalCommand {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  int count = 1;
};

// What an earlier restore wrote (or found) at an address: a later restore
// leaves the address alone when it no longer holds this value.
struct JournalRestored {
  spec::Table table = spec::Table::holding;
  uint16_t address = 0;
  std::vector<uint16_t> value;
};

// A line that failed its checksum or could not be read (1-based line number).
struct JournalTorn {
  int line = 0;
  bool last = false;  // the file's last line: cut off while being written
  std::string why;
};

// The largest journal `read_journal` accepts (a journal holds at most a few
// lines per address of two tables).
inline constexpr size_t kMaxJournalBytes = 64u << 20;

// Everything a journal holds, read from its file or kept in memory as it was
// written.
struct JournalContents {
  std::map<std::string, std::string> header;  // target, device, spec, spec-crc32, unit, command, started, identity
  std::vector<JournalEntry> originals;         // the first of each address, in journal order
  std::vector<JournalUnread> unread;
  std::vector<JournalCommand> commands;
  std::vector<JournalRestored> restored;       // the latest restored/verified value of each address, in order
  std::vector<std::string> restore_lines;      // restored/verified/not-restored/left/end lines
  std::vector<JournalTorn> torn;
  // `control STATE KEY=WORD...`: the drive's control state (spec control:)
  // before the command's first write to a control command register, and
  // the status words that named it. The first one counts.
  std::string control_state;
  std::string control_status;
  int format = 2;
  bool ended = false;  // an `end` line came
};

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
  // Appends the originals (unread items, command registers written) and
  // fsyncs before returning: only then may the write go out. Throws
  // std::runtime_error on I/O errors (then failed() says why, and nothing of
  // this call counts as kept; memory() still has it).
  void keep(const std::vector<JournalEntry>& originals, const std::vector<JournalUnread>& unread = {},
            const std::vector<JournalCommand>& commands = {});
  // A record (fsync'd): the identity, a restore's lines. Throws like keep().
  void record(const std::string& line);
  // record(), and false (with failed() set) instead of a throw.
  bool try_record(const std::string& line);
  const std::string& path() const { return path_; }
  bool open() const { return fd_ >= 0; }
  size_t kept() const { return kept_; }
  // Why the last write to the file failed (a full disk), or empty.
  const std::string& failed() const { return failed_; }
  // What this process asked the journal to keep, whether or not it reached
  // the disk (a restore when the disk is full puts the drive back from it).
  const JournalContents& memory() const { return memory_; }

 private:
  void write_records(const std::vector<std::string>& lines);
  int fd_ = -1;
  std::string path_;
  std::set<std::pair<spec::Table, uint16_t>> covered_;
  size_t kept_ = 0;
  std::string failed_;
  bool partial_ = false;  // a write left a line without its end: the next starts on a new line
  JournalContents memory_;
};

// Reads a journal: std::runtime_error "PATH: ..." for a file over
// kMaxJournalBytes or one that is not a journal. A damaged line is not an
// error: it is listed in `torn` and skipped.
JournalContents read_journal(const std::string& path);

// What `memory` holds that `disk` does not (a record the disk would not
// take), added to `disk`.
JournalContents merge_journal(JournalContents disk, const JournalContents& memory);

// The record's text with its checksum (" *1A2B3C4D"), and the check.
std::string journal_line(const std::string& text);
// CRC-32 (IEEE 802.3) of `bytes` (also the spec file's fingerprint).
uint32_t journal_crc32(std::string_view bytes);

const char* journal_table_name(spec::Table);

}  // namespace mbc::conf
