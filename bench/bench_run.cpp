// The whole conformance run against each reference drive served by
// `mbconform serve --line-rate BAUD --baud BAUD` on a pty (a real serial line's pacing),
// through the rtu:// live target: wall time against the run's wire-time lower
// bound (every byte at the baud rate plus the 3.5-character gaps, MB-SL v1.02
// §2.5.1.1), measured in the same run. A case that expects silence must wait
// for it, which no wire-time bound counts; so a second bound adds, for every
// exchange that got no reply, the p99 reply latency measured in the same run
// (the least a master can wait before it calls a silence). Targets: wall <=
// 1.5 x the wire-time bound, and <= 1.1 x the bound with the silences.
// It times the command a user runs (`mbconform run ... --out DIR`, its
// session, preflight and all) and reads the figures from its report.json:
// no second copy of the run's pipeline here.
//
// Then, for each third-party server of conformance/peers/servers/ (libmodbus,
// pymodbus, modbus-serial when built), what `run --map auto --device
// modbus-standard --allow-writes` costs over loopback TCP: the probe's time
// and requests, the run's time, and the probe as a fraction of the whole.
//
//   build/bin/mbc_bench_run [path/to/mbconform] [--baud 115200] [--baud 9600] [--device ID]... [--no-peers]
// (from the source root: the peers' scripts are read from conformance/peers/servers/)
#include <fmt/core.h>
#include <signal.h>
#include <fcntl.h>
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

#include <netinet/in.h>
#include <sys/socket.h>

#include <fstream>
#include <nlohmann/json.hpp>

namespace {

// A server in a child process (its own process group), ready when it prints
// a line starting with `ready`; killed when the object goes away.
class Child {
 public:
  Child(const std::vector<std::string>& argv, const std::string& ready, const std::vector<std::string>& env = {}) {
    int out[2];
    if (pipe(out) != 0) throw std::runtime_error("pipe");
    pid_ = fork();
    if (pid_ == 0) {
      setpgid(0, 0);
      dup2(out[1], 1);
      close(out[0]);
      for (const auto& e : env) putenv(const_cast<char*>(e.c_str()));
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      execvp(args[0], args.data());
      _exit(127);
    }
    close(out[1]);
    FILE* f = fdopen(out[0], "r");
    char line[512];
    bool ok = false;
    while (f && fgets(line, sizeof line, f))
      if (std::string(line).rfind(ready, 0) == 0) {
        ok = true;
        break;
      }
    out_ = f;
    if (!ok) throw std::runtime_error("did not start: " + argv.front());
  }
  ~Child() {
    kill(-pid_, SIGTERM);
    kill(pid_, SIGTERM);
    int st = 0;
    waitpid(pid_, &st, 0);
    if (out_) fclose(out_);
  }

 private:
  pid_t pid_ = -1;
  FILE* out_ = nullptr;
};

// A loopback port nothing listens on right now.
int free_port() {
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a);
  socklen_t len = sizeof a;
  getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  close(fd);
  return ntohs(a.sin_port);
}

// `mbconform run ARGS... --quiet --out DIR`: its report.json's first device
// (throws when the run wrote none: it could not be done).
nlohmann::json run_report(const std::string& exe, std::vector<std::string> args, const std::string& out) {
  args.insert(args.begin(), {exe, "run"});
  for (const char* a : {"--quiet", "--out"}) args.push_back(a);
  args.push_back(out);
  pid_t pid = fork();
  if (pid == 0) {
    int null = open("/dev/null", O_WRONLY);
    dup2(null, 1);
    dup2(null, 2);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  int st = 0;
  waitpid(pid, &st, 0);
  std::ifstream in(out + "/report.json");
  if (!in) throw std::runtime_error(fmt::format("mbconform run wrote no report (exit {})", WEXITSTATUS(st)));
  nlohmann::json j = nlohmann::json::parse(in);
  if (j["devices"].empty()) throw std::runtime_error("mbconform run's report names no device");
  return j["devices"][0];
}

size_t count_fails(const nlohmann::json& dev) {
  size_t n = 0;
  for (const auto& c : dev["cases"]) n += c["outcome"] == "fail";
  return n;
}

// `run --map auto --device modbus-standard --allow-writes` against each
// third-party server: the probe's and the run's time.
void bench_peers(const std::string& exe, const std::string& dir) {
  namespace fs = std::filesystem;
  fs::path bin = fs::path(exe).parent_path(), peers = "conformance/peers/servers";
  struct Peer {
    std::string name;
    std::vector<std::string> argv, env;
  };
  std::vector<Peer> list = {{"libmodbus 3.1.6", {(bin / "libmodbus_peer_server").string()}, {}},
                            {"pymodbus 3.0", {"/usr/bin/python3", (peers / "pymodbus_server.py").string()}, {}}};
  if (fs::exists(bin / "../peers/node_modules/modbus-serial"))
    list.push_back({"modbus-serial", {"node", (peers / "modbus_serial_server.js").string()},
                    {"NODE_PATH=" + (bin / "../peers/node_modules").string()}});
  fmt::print("\n{:<18} {:>9} {:>9} {:>6} {:>7} {:>9} {:>8} {:>10}\n", "server", "probe s", "requests", "cases", "fails",
             "run s", "total s", "probe/total");
  for (auto& p : list) {
    int port = free_port();
    p.argv.push_back(std::to_string(port));
    try {
      Child server(p.argv, "listening", p.env);
      auto dev = run_report(exe,
                            {"--map", "auto", "--device", "modbus-standard", "--allow-writes", "--target",
                             fmt::format("tcp://127.0.0.1:{}?unit=1", port)},
                            dir + "/peer-" + std::to_string(port));
      // The probe's figures are in the run's notes ("map probed in N requests, S s: ...").
      unsigned requests = 0;
      double probe_s = 0;
      for (const auto& n : dev["notes"])
        if (std::sscanf(n.get<std::string>().c_str(), "map probed in %u requests, %lf s", &requests, &probe_s) == 2) break;
      double run_s = dev["wall_seconds"].get<double>(), total = probe_s + run_s;
      fmt::print("{:<18} {:>9.2f} {:>9} {:>6} {:>7} {:>9.2f} {:>8.2f} {:>10.2f}\n", p.name, probe_s, requests, dev["cases"].size(),
                 count_fails(dev), run_s, total, total > 0 ? probe_s / total : 0);
    } catch (const std::exception& e) {
      fmt::print("{:<18} not run: {}\n", p.name, e.what());
    }
    std::fflush(stdout);
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::string exe = "build/bin/mbconform";
  std::vector<int> bauds;
  std::vector<std::string> devices;
  bool peers = true;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--no-peers") peers = false;
    else if (a == "--baud" && i + 1 < argc) bauds.push_back(std::atoi(argv[++i]));
    else if (a == "--device" && i + 1 < argc) devices.push_back(argv[++i]);
    else exe = a;
  }
  if (bauds.empty()) bauds = {115200, 9600};
  if (devices.empty()) devices = {"sihong-57hs-r", "hsc60", "hanstar-7trsm5740q", "rieding-dhe"};
  std::string dir = std::filesystem::temp_directory_path() / fmt::format("mbc_bench_run.{}", getpid());
  std::filesystem::create_directories(dir);

  fmt::print("{:<20} {:>7} {:>6} {:>7} {:>9} {:>10} {:>12} {:>7} {:>9} {:>15} {:>7}  {}\n", "device", "baud", "cases", "frames",
             "silences", "wall s", "wire bound s", "ratio", "p99 ms", "+silences s", "ratio", "(targets 1.50, 1.10)");
  int over = 0;
  for (int baud : bauds) {
    for (const auto& id : devices) {
      std::string pty = dir + "/tty-" + id;
      std::string rate = std::to_string(baud);
      Child serve({exe, "serve", "--device", id + "@1", "--pty", pty, "--line-rate", rate, "--baud", rate}, "listening pty");
      auto dev = run_report(exe, {"--device", id, "--target", fmt::format("rtu://{}?baud={}&unit=1", pty, baud)},
                            dir + "/run-" + id + "-" + rate);
      double wall = dev["wall_seconds"].get<double>(), bound = dev["wire_time_bound_seconds"].get<double>();
      size_t silences = dev["silences"].get<size_t>(), frames = dev["frames_sent"].get<size_t>();
      double ratio = bound > 0 ? wall / bound : 0;
      std::vector<double> lat = dev["latencies_us"].get<std::vector<double>>();
      double p99 = 0;
      if (!lat.empty()) {
        size_t at = std::min(lat.size() - 1, size_t(double(lat.size()) * 0.99));
        std::nth_element(lat.begin(), lat.begin() + ptrdiff_t(at), lat.end());
        p99 = lat[at] / 1e6;
      }
      double bound2 = bound + double(silences) * p99;
      double ratio2 = bound2 > 0 ? wall / bound2 : 0;
      size_t must_failed = 0;
      std::string failed;
      for (const auto& c : dev["cases"])
        if (c["outcome"] == "fail" && c["level"] == "MUST" && !c.contains("quirk")) {
          ++must_failed;
          failed += fmt::format("    MUST failed: {}: {}\n", c["id"].get<std::string>(), c["message"].get<std::string>());
        }
      fmt::print("{:<20} {:>7} {:>6} {:>7} {:>9} {:>10.2f} {:>12.2f} {:>7.2f} {:>9.2f} {:>15.2f} {:>7.2f}  {}{}\n", id, baud,
                 dev["cases"].size(), frames, silences, wall, bound, ratio, p99 * 1e3,
                 bound2, ratio2, ratio <= 1.5 && ratio2 <= 1.1 ? "ok" : "OVER",
                 must_failed ? fmt::format(" ({} MUST failed)", must_failed) : "");
      fmt::print("{}", failed);
      std::fflush(stdout);
      over += ratio > 1.5 || ratio2 > 1.1;
    }
  }
  fmt::print("serve holds each reply for the line time of the request and the reply plus t3.5, so the pty\n"
             "behaves like the wire: the bound is a true lower bound and the ratio is the runner's overhead.\n");
  if (peers) bench_peers(exe, dir);
  std::filesystem::remove_all(dir);
  return over ? 1 : 0;
}
