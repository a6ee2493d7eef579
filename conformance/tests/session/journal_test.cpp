// The journal's file (conformance/session/journal.h, README.md): every record
// checksummed; a record cut off or damaged is named and skipped, never read
// as a value, and the rest still reads; a full file stops the journal with
// the record kept in memory.
#include <fmt/core.h>
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "serve_process.h"
#include "session/journal.h"

namespace mbc::conf {
namespace {

using serve_test::TempDir;

std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void spit(const std::string& path, const std::string& text) { std::ofstream(path, std::ios::binary | std::ios::trunc) << text; }

std::string two_values(const TempDir& dir) {
  Journal j = Journal::create(dir.path(), {{"device", "hsc60"}, {"unit", "1"}});
  j.keep({{spec::Table::holding, 0x0010, {0x1234}, false, ""}});
  j.keep({{spec::Table::holding, 0x0020, {0xABCD}, false, ""}});
  return j.path();
}

TEST(Journal, ALineCutInsideAValueIsNamedAndNeverReadAsAValue) {
  TempDir dir;
  const std::string path = two_values(dir);
  const std::string text = slurp(path);
  ASSERT_EQ(text.back(), '\n');
  // Cut inside "ABCD": the torn word must not become 0x00AB or 0x0000.
  const auto at = text.rfind("ABCD");
  ASSERT_NE(at, std::string::npos);
  for (size_t cut : {at + 2, at + 4, text.size() - 3}) {
    spit(path, text.substr(0, cut));
    JournalContents c = read_journal(path);
    ASSERT_EQ(c.originals.size(), 1u) << cut;
    EXPECT_EQ(c.originals[0].address, 0x0010);
    EXPECT_EQ(c.originals[0].value, std::vector<uint16_t>{0x1234});
    ASSERT_EQ(c.torn.size(), 1u) << cut;
    EXPECT_TRUE(c.torn[0].last);
    EXPECT_EQ(c.torn[0].line, int(std::count(text.begin(), text.begin() + long(at), '\n')) + 1);
  }
  // Whole again, both read.
  spit(path, text);
  EXPECT_EQ(read_journal(path).originals.size(), 2u);
  EXPECT_TRUE(read_journal(path).torn.empty());
}

TEST(Journal, ADamagedLineElsewhereIsSkippedAndTheRestStillReads) {
  TempDir dir;
  const std::string path = two_values(dir);
  std::string text = slurp(path);
  const auto at = text.find("1234");
  ASSERT_NE(at, std::string::npos);
  text[at] = '7';  // 0x7234: a value the checksum no longer covers
  spit(path, text);
  JournalContents c = read_journal(path);
  ASSERT_EQ(c.originals.size(), 1u);
  EXPECT_EQ(c.originals[0].address, 0x0020);
  ASSERT_EQ(c.torn.size(), 1u);
  EXPECT_FALSE(c.torn[0].last);
  EXPECT_NE(c.torn[0].why.find("checksum"), std::string::npos) << c.torn[0].why;
  // An unchecksummed line (a hand edit, another tool) is not taken either.
  std::ofstream(path, std::ios::app) << "orig holding 0x0030 1 0000\n";
  c = read_journal(path);
  EXPECT_EQ(c.originals.size(), 1u);
  EXPECT_EQ(c.torn.size(), 2u);
}

TEST(Journal, FormatOneIsStillReadAndItsCutWordIsNotAValue) {
  TempDir dir;
  spit(dir / "j.txt", "mbconform-journal 1\ndevice hsc60\nunit 1\norig holding 0x0010 1 1234\norig holding 0x0020 1 00");
  JournalContents c = read_journal(dir / "j.txt");
  EXPECT_EQ(c.format, 1);
  EXPECT_EQ(c.header["device"], "hsc60");
  ASSERT_EQ(c.originals.size(), 1u);
  EXPECT_EQ(c.originals[0].value, std::vector<uint16_t>{0x1234});
  ASSERT_EQ(c.torn.size(), 1u);
  EXPECT_EQ(c.torn[0].line, 5);
}

TEST(Journal, FirstValueOfAnAddressIsTheOriginalAndTheFileIsBounded) {
  TempDir dir;
  std::string path;
  {
    Journal j = Journal::create(dir.path(), {{"target", "rtu:///dev/null?unit=1"}, {"device", "hsc60"}, {"unit", "1"}});
    path = j.path();
    j.keep({{spec::Table::holding, 0x0016, {0}, true, ""}, {spec::Table::holding, 0x0020, {0x1234, 0x5678}, false, ""}});
    EXPECT_TRUE(j.has(spec::Table::holding, 0x0021));
    j.keep({}, {{spec::Table::holding, 0x0100, 2, "exception 02"}}, {{spec::Table::holding, 0x0200, 1}});
    EXPECT_TRUE(j.has(spec::Table::holding, 0x0200));
  }
  {
    // A forked child journaling again appends a later value: ignored.
    std::ofstream(path, std::ios::app) << journal_line("orig holding 0x0020 2 0000 0000") << "\n";
  }
  JournalContents c = read_journal(path);
  EXPECT_EQ(c.header["device"], "hsc60");
  ASSERT_EQ(c.originals.size(), 2u);
  EXPECT_TRUE(c.originals[0].persist_switch);
  EXPECT_EQ(c.originals[1].value, (std::vector<uint16_t>{0x1234, 0x5678}));
  ASSERT_EQ(c.unread.size(), 1u);
  EXPECT_EQ(c.unread[0].why, "exception 02");
  ASSERT_EQ(c.commands.size(), 1u);
  EXPECT_EQ(c.commands[0].address, 0x0200);
  EXPECT_TRUE(c.torn.empty());
  spit(dir / "bad.txt", "not a journal\n");
  EXPECT_THROW(read_journal(dir / "bad.txt"), std::runtime_error);
  EXPECT_THROW(read_journal("/dev/zero"), std::runtime_error);
  EXPECT_THROW(read_journal(dir / "missing.txt"), std::runtime_error);
}

// A restore's records carry the values it wrote: a later restore compares with them.
TEST(Journal, RestoredRecordsKeepTheirValues) {
  TempDir dir;
  const std::string path = two_values(dir);
  {
    Journal j = Journal::append_to(path);
    j.record("restored holding 0x0010 1 1234");
    j.record("verified holding 0x0010 1 1234");
    j.record("verified holding 0x0020 1 ABCD");
  }
  JournalContents c = read_journal(path);
  ASSERT_EQ(c.restored.size(), 2u);
  EXPECT_EQ(c.restored[1].value, std::vector<uint16_t>{0xABCD});
}

// A file-size limit (or a full disk) in the middle of a record: the record
// is torn on disk, keep() throws and says why, memory() still holds it, and
// a record appended later starts on its own line.
TEST(Journal, AFullFileStopsTheJournalAndMemoryKeepsTheRecord) {
  TempDir dir;
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    signal(SIGXFSZ, SIG_IGN);  // as mbconform's main() does: EFBIG, not the end of the process
    std::string out;
    try {
      Journal j = Journal::create(dir.path(), {{"device", "hsc60"}, {"unit", "1"}});
      j.keep({{spec::Table::holding, 0x0010, {0x1234}, false, ""}});
      off_t size = std::filesystem::file_size(j.path());
      rlimit lim{rlim_t(size + 10), rlim_t(size + 10)};
      setrlimit(RLIMIT_FSIZE, &lim);
      try {
        j.keep({{spec::Table::holding, 0x0020, {0xABCD}, false, ""}});
        out = "kept";
      } catch (const std::exception& e) {
        out = fmt::format("threw|{}|{}|{}|{}", j.failed(), j.memory().originals.size(), j.has(spec::Table::holding, 0x0020),
                          j.path());
      }
    } catch (const std::exception& e) {
      out = std::string("create failed: ") + e.what();
    }
    (void)!write(fds[1], out.data(), out.size());
    _exit(0);
  }
  close(fds[1]);
  std::string got;
  char buf[512];
  for (ssize_t n; (n = read(fds[0], buf, sizeof buf)) > 0;) got.append(buf, size_t(n));
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFEXITED(status)) << "killed by signal " << WTERMSIG(status) << " (SIGXFSZ is ignored: the journal must fail with EFBIG)";
  ASSERT_EQ(got.rfind("threw|", 0), 0u) << got;
  std::istringstream parts(got.substr(6));
  std::string failed, in_memory, has, path;
  std::getline(parts, failed, '|');
  std::getline(parts, in_memory, '|');
  std::getline(parts, has, '|');
  std::getline(parts, path, '|');
  EXPECT_NE(failed.find("File too large"), std::string::npos) << failed;
  EXPECT_EQ(in_memory, "2");
  EXPECT_EQ(has, "false") << "a record not on disk does not count as kept";
  JournalContents c = read_journal(path);
  ASSERT_EQ(c.originals.size(), 1u);
  ASSERT_EQ(c.torn.size(), 1u);
  EXPECT_TRUE(c.torn[0].last);
  // A restore appending after the torn line: its record is whole.
  {
    Journal j = Journal::append_to(path);
    j.record("verified holding 0x0010 1 1234");
  }
  c = read_journal(path);
  EXPECT_EQ(c.torn.size(), 1u);
  EXPECT_FALSE(c.torn[0].last);
  EXPECT_EQ(c.restored.size(), 1u);
}

TEST(Journal, Crc32IsTheStandardOne) {
  // The check value of CRC-32/ISO-HDLC.
  EXPECT_EQ(journal_crc32("123456789"), 0xCBF43926u);
}

}  // namespace
}  // namespace mbc::conf
