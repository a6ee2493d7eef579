// Stopping a command that talks to a drive (README.md, "Live drives"):
// SIGINT, SIGTERM and SIGHUP ask the command to stop sending; it then
// restores the drive, writes its partial report (INCOMPLETE) and exits 2. A
// second SIGINT or SIGTERM ends the process at once (exit 2) and leaves the
// journal for `mbconform restore`, whose command line it prints.
#pragma once

#include <atomic>
#include <string>
#include <vector>

namespace mbc::conf {

// Installs the handlers (idempotent); every command that opens a target calls it.
void install_stop_signals();
// Whether a stop was asked, and by which signal (0: none).
bool stop_requested();
int stop_signal();
const std::atomic<bool>& stop_flag();
// The journals a second signal names, one line each ("mbconform restore
// PATH"): every session open now (a fleet run has one per line) adds its
// own, and forgets it once the drive is restored.
void set_stop_journal(const std::string& path);
void forget_stop_journal(const std::string& path);
std::vector<std::string> stop_journals();  // the paths named now
// The signal's name for messages ("SIGINT").
std::string signal_name(int sig);

}  // namespace mbc::conf
