// A run through a Modbus TCP gateway that retries, beside the same run served
// directly, in the same process tree and the same minute (issue 36: "a run
// through a gateway that retries finishes within 2x the wire time of the same
// run served directly").
//
// The drive: `mbconform serve --device ID@1 --rtu-tcp ... --line-rate BAUD`,
// RTU replies paced at the line's wire time. Served directly: `run --target
// rtu-tcp://...?baud=BAUD`, whose report.json gives its wall time and its
// wire-time bound (every byte at BAUD plus the 3.5-character gaps). Through the
// gateway: conformance/tests/runner/retrying_gateway.py (a TCP-to-RTU gateway
// written in the tests from the TCP IG and MB-SL: one request on the line at a
// time, --retries tries of --try-ms each, then exception 0B) in front of the
// same served drive, `run --target tcp://GATEWAY?unit=1&gateway=1` and again
// with the gateway left to be detected. Both runs send the same cases
// (--allow-disruptive: listen-only and restart are what a gateway answers for).
//
// Figures: the gateway run's wall time over the direct run's wire-time bound
// (target at most 2.0) and over the direct run's wall time; MUST failures of
// every run (a ratio of a run that failed is not a result). Exit 1 when a
// target is not met, 2 when a run could not be made.
//
//   build/bin/mbc_bench_gateway [path/to/mbconform] [--baud 19200] [--device ID]
//                               [--gw TRY_MS:RETRIES]...   (default 500:3, mbusd's; a try shorter than the
//                               line's longest reply, 40 ms at 19200, retries what was answered)
//                               [--timeout MS]   (the gateway URIs' timeout=: a gateway that gives up after
//                               longer than the target's timeout, 1 s by default, answers its 0B late)
// (from the source root: the gateway script is read from conformance/tests/runner/)
#include <fmt/core.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

// A server process that prints "listening KIND HOST:PORT" when ready: its port;
// the process group is ended when this goes away.
class Server {
 public:
  explicit Server(const std::vector<std::string>& argv) {
    int fds[2];
    if (pipe(fds) != 0) throw std::runtime_error("pipe");
    pid_ = fork();
    if (pid_ == 0) {
      setpgid(0, 0);
      dup2(fds[1], 1);
      close(fds[0]);
      std::vector<char*> args;
      for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      execvp(args[0], args.data());
      _exit(127);
    }
    close(fds[1]);
    out_ = fdopen(fds[0], "r");
    char line[512];
    while (out_ && fgets(line, sizeof line, out_)) {
      std::string s = line;
      if (s.rfind("listening ", 0) == 0) {
        port_ = std::stoi(s.substr(s.rfind(':') + 1));
        return;
      }
    }
    throw std::runtime_error("did not start: " + argv.front());
  }
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;
  ~Server() {
    kill(-pid_, SIGTERM);
    int st = 0;
    waitpid(pid_, &st, 0);
    if (out_) fclose(out_);
  }
  int port() const { return port_; }

 private:
  pid_t pid_ = -1;
  FILE* out_ = nullptr;
  int port_ = 0;
};

// `mbconform run --quiet --allow-disruptive --device ID --target URI --out DIR`: its
// report.json's first device.
nlohmann::json run(const std::string& exe, const std::string& device, const std::string& uri, const std::string& out) {
  std::string cmd = fmt::format("'{}' run --quiet --allow-disruptive --device {} --target '{}' --out '{}' >/dev/null 2>&1", exe,
                                device, uri, out);
  int st = std::system(cmd.c_str());
  std::ifstream in(out + "/report.json");
  if (!in) throw std::runtime_error(fmt::format("{}: no report (exit {})", uri, WEXITSTATUS(st)));
  auto j = nlohmann::json::parse(in);
  if (j["devices"].empty()) throw std::runtime_error(uri + ": the report names no device");
  return j["devices"][0];
}

}  // namespace

int main(int argc, char** argv) {
  std::string exe = "build/bin/mbconform", device = "modbus-standard";
  int baud = 19200, timeout_ms = 0;
  std::vector<std::pair<int, int>> gateways;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--baud" && i + 1 < argc) baud = std::atoi(argv[++i]);
    else if (a == "--device" && i + 1 < argc) device = argv[++i];
    else if (a == "--timeout" && i + 1 < argc) timeout_ms = std::atoi(argv[++i]);
    else if (a == "--gw" && i + 1 < argc) {
      int t = 0, r = 0;
      if (std::sscanf(argv[++i], "%d:%d", &t, &r) != 2 || t <= 0 || r < 0) {
        fmt::print(stderr, "mbc_bench_gateway: --gw TRY_MS:RETRIES, as 500:3\n");
        return 2;
      }
      gateways.emplace_back(t, r);
    } else exe = a;
  }
  if (gateways.empty()) gateways = {{500, 3}};
  const std::string script = "conformance/tests/runner/retrying_gateway.py";
  if (!std::filesystem::exists(script)) {
    fmt::print(stderr, "mbc_bench_gateway: {} not found: run from the source root\n", script);
    return 2;
  }
  std::string dir = std::filesystem::temp_directory_path() / fmt::format("mbc_bench_gateway.{}", getpid());
  std::filesystem::create_directories(dir);
  int rc = 0;
  try {
    Server serve({exe, "serve", "--device", device + "@1", "--rtu-tcp", "127.0.0.1:0", "--line-rate", std::to_string(baud)});
    auto direct = run(exe, device, fmt::format("rtu-tcp://127.0.0.1:{}?unit=1&baud={}", serve.port(), baud), dir + "/direct");
    double wire = direct["wire_time_bound_seconds"].get<double>(), wall = direct["wall_seconds"].get<double>();
    int must = direct["counts"]["must_failed"].get<int>();
    fmt::print("{} at {} baud, {} cases\n", device, baud, direct["cases"].size());
    fmt::print("{:<46} {:>8} {:>11} {:>12} {:>11}\n", "run", "wall s", "MUST fails", "/ wire time", "/ direct");
    fmt::print("{:<46} {:>8.2f} {:>11} {:>12.2f} {:>11.2f}\n", "served directly (rtu-tcp)", wall, must, wall / wire, 1.0);
    fmt::print("{:<46} {:>8.2f}\n", "  its wire-time bound", wire);
    if (must) rc = 1;
    for (auto [try_ms, retries] : gateways) {
      Server gw({"/usr/bin/python3", script, std::to_string(serve.port()), "--try-ms", std::to_string(try_ms), "--retries",
                 std::to_string(retries)});
      for (const char* mode : {"&gateway=1", ""}) {
        std::string extra = timeout_ms > 0 ? fmt::format("&timeout={}", timeout_ms) : "";
        auto d = run(exe, device, fmt::format("tcp://127.0.0.1:{}?unit=1{}{}", gw.port(), mode, extra),
                     fmt::format("{}/gw-{}-{}{}", dir, try_ms, retries, *mode ? "-given" : "-detected"));
        double w = d["wall_seconds"].get<double>();
        int m = d["counts"]["must_failed"].get<int>();
        fmt::print("{:<46} {:>8.2f} {:>11} {:>12.2f} {:>11.2f}\n",
                   fmt::format("gateway {} ms x {}, {}{}", try_ms, 1 + retries, *mode ? "given" : "detected",
                               timeout_ms > 0 ? fmt::format(", timeout={}", timeout_ms) : ""),
                   w, m, w / wire,
                   w / wall);
        for (const auto& c : d["cases"])
          if (c["outcome"] == "fail" && c.value("level", "") == "MUST")
            fmt::print("    MUST failed: {}: {}\n", c["id"].get<std::string>(), c.value("message", "").substr(0, 160));
        if (m || w > 2.0 * wire) rc = 1;
      }
    }
  } catch (const std::exception& e) {
    fmt::print(stderr, "mbc_bench_gateway: {}\n", e.what());
    rc = 2;
  }
  fmt::print("target: a gateway run's wall time at most 2.0 x the direct run's wire time, no MUST failure\n");
  std::filesystem::remove_all(dir);
  return rc;
}
