// The whole conformance run against each reference drive served by
// `mbconform serve --line-rate BAUD --baud BAUD` on a pty (a real serial line's pacing),
// through the rtu:// live target: wall time against the run's wire-time lower
// bound (every byte at the baud rate plus the 3.5-character gaps, MB-SL v1.02
// §2.5.1.1), measured in the same run. A case that expects silence must wait
// for it, which no wire-time bound counts; so a second bound adds, for every
// exchange that got no reply, the p99 reply latency measured in the same run
// (the least a master can wait before it calls a silence). Targets: wall <=
// 1.5 x the wire-time bound, and <= 1.1 x the bound with the silences.
//
//   build/bin/mbc_bench_run [path/to/mbconform] [--baud 115200] [--baud 9600] [--device ID]...
#include <fmt/core.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "cases/case.h"
#include "loader.h"
#include "runner/runner.h"

namespace {

// `mbconform serve` in a child process, until the object goes away.
class Serve {
 public:
  Serve(const std::string& exe, const std::string& device, const std::string& pty, int baud) {
    int out[2];
    if (pipe(out) != 0) throw std::runtime_error("pipe");
    pid_ = fork();
    if (pid_ == 0) {
      dup2(out[1], 1);
      close(out[0]);
      std::string dev = device + "@1", rate = std::to_string(baud);
      execl(exe.c_str(), exe.c_str(), "serve", "--device", dev.c_str(), "--pty", pty.c_str(), "--line-rate", rate.c_str(),
            "--baud", rate.c_str(), (char*)nullptr);
      _exit(127);
    }
    close(out[1]);
    FILE* f = fdopen(out[0], "r");
    char line[512];
    bool ok = false;
    while (f && fgets(line, sizeof line, f))
      if (std::string(line).rfind("listening pty", 0) == 0) {
        ok = true;
        break;
      }
    out_ = f;
    if (!ok) throw std::runtime_error("mbconform serve did not start: " + exe);
  }
  ~Serve() {
    kill(pid_, SIGTERM);
    int st = 0;
    waitpid(pid_, &st, 0);
    if (out_) fclose(out_);
  }

 private:
  pid_t pid_ = -1;
  FILE* out_ = nullptr;
};

}  // namespace

int main(int argc, char** argv) {
  std::string exe = "build/bin/mbconform";
  std::vector<int> bauds;
  std::vector<std::string> devices;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--baud" && i + 1 < argc) bauds.push_back(std::atoi(argv[++i]));
    else if (a == "--device" && i + 1 < argc) devices.push_back(argv[++i]);
    else exe = a;
  }
  if (bauds.empty()) bauds = {115200, 9600};
  if (devices.empty()) devices = {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"};
  auto standard = mbc::spec::load_spec_by_id("modbus-standard");
  std::string dir = std::filesystem::temp_directory_path() / fmt::format("mbc_bench_run.{}", getpid());
  std::filesystem::create_directories(dir);

  fmt::print("{:<20} {:>7} {:>6} {:>7} {:>9} {:>10} {:>12} {:>7} {:>9} {:>15} {:>7}  {}\n", "device", "baud", "cases", "frames",
             "silences", "wall s", "wire bound s", "ratio", "p99 ms", "+silences s", "ratio", "(targets 1.50, 1.10)");
  int over = 0;
  for (int baud : bauds) {
    for (const auto& id : devices) {
      std::string pty = dir + "/tty-" + id;
      Serve serve(exe, id, pty, baud);
      auto spec = mbc::spec::load_spec_by_id(id);
      auto target = mbc::conf::open_target(fmt::format("rtu://{}?baud={}&unit=1", pty, baud));
      mbc::conf::GenContext g{spec, target->info(), {}, &standard};
      auto cases = mbc::conf::all_cases(g);
      auto run = mbc::conf::run_cases(*target, spec, cases);
      double ratio = run.wire_time_bound_seconds > 0 ? run.wall_seconds / run.wire_time_bound_seconds : 0;
      std::vector<double> lat = run.latencies_us;
      double p99 = 0;
      if (!lat.empty()) {
        size_t at = std::min(lat.size() - 1, size_t(double(lat.size()) * 0.99));
        std::nth_element(lat.begin(), lat.begin() + ptrdiff_t(at), lat.end());
        p99 = lat[at] / 1e6;
      }
      double bound2 = run.wire_time_bound_seconds + double(run.silences) * p99;
      double ratio2 = bound2 > 0 ? run.wall_seconds / bound2 : 0;
      size_t must_failed = 0;
      for (const auto& c : run.cases) must_failed += c.outcome == mbc::conf::Outcome::fail && c.level == mbc::conf::Level::must;
      fmt::print("{:<20} {:>7} {:>6} {:>7} {:>9} {:>10.2f} {:>12.2f} {:>7.2f} {:>9.2f} {:>15.2f} {:>7.2f}  {}{}\n", id, baud,
                 run.cases.size(), run.frames_sent, run.silences, run.wall_seconds, run.wire_time_bound_seconds, ratio, p99 * 1e3,
                 bound2, ratio2, ratio <= 1.5 && ratio2 <= 1.1 ? "ok" : "OVER",
                 must_failed ? fmt::format(" ({} MUST failed)", must_failed) : "");
      std::fflush(stdout);
      over += ratio > 1.5 || ratio2 > 1.1;
    }
  }
  fmt::print("serve holds each reply for the line time of the request and the reply plus t3.5, so the pty\n"
             "behaves like the wire: the bound is a true lower bound and the ratio is the runner's overhead.\n");
  std::filesystem::remove_all(dir);
  return over ? 1 : 0;
}
