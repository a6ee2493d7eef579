// check-capture against tshark on the same file, side by side in one run:
// `tshark -r FILE -Y mbtcp` (the Modbus/TCP dissector, output to /dev/null)
// and `mbconform check-capture FILE --device modbus-standard` (read, pair,
// judge, write the reports), each timed as a child process, with the
// child's peak RSS (getrusage). Target: check-capture at least 5x tshark's
// speed, and under 200 MB RSS whatever the file's size (a capture is
// streamed). The speed target is judged on the children's CPU time (user +
// system, from wait4), which other work on a shared machine does not
// inflate; the wall-clock ratio is printed beside it. The capture is generated here: Modbus TCP conversations of FC 03
// reads, FC 06 and FC 16 writes and exception replies, over Ethernet/IPv4/TCP
// (modbus/pcapng.h), as many as fit in --mb megabytes.
//
//   build/bin/mbc_bench_capture build/bin/mbconform [--mb 64] [--no-tshark] [--keep FILE]
//
// Exit 0 when the targets are met, 1 when one is not, 2 on a usage error.
#include <fmt/core.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "modbus/mbap.h"
#include "modbus/pcapng.h"
#include "modbus/pdu.h"

namespace {

using namespace mbc;

// Writes a capture of about `mb` megabytes; returns the number of requests.
uint64_t generate(const std::string& path, uint64_t mb) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot write " + path);
  auto put = [&](const Bytes& b) { std::fwrite(b.data(), 1, b.size(), f); };
  put(pcapng::section_header("mbc_bench_capture"));
  put(pcapng::interface_description(pcapng::kLinkEthernet, "eth0", ""));
  uint64_t t = 1'700'000'000'000'000, bytes = 0, requests = 0, limit = mb << 20;
  uint16_t port = 1024;
  while (bytes < limit) {
    pcapng::TcpConversation c(0x0A000001, port, 0x0A000002, 502);
    port = uint16_t(port == 65000 ? 1024 : port + 1);
    auto packet = [&](const Bytes& frame, uint64_t dt) {
      t += dt;
      Bytes b = pcapng::enhanced_packet(0, t, frame);
      bytes += b.size();
      put(b);
    };
    for (int s = 0; s < 3; ++s) packet(c.handshake(s), 50);
    for (uint16_t tid = 1; tid <= 200; ++tid) {
      Bytes rq, rp;
      uint16_t addr = uint16_t((tid * 7) % 250);
      switch (tid % 5) {
        case 0: {  // FC 16, 4 registers
          const uint16_t v[4] = {tid, 2, 3, 4};
          rq = write_multiple_registers(addr, v);
          rp = {0x10, uint8_t(addr >> 8), uint8_t(addr), 0, 4};
          break;
        }
        case 1:  // FC 06
          rq = write_single_register(addr, tid);
          rp = rq;
          break;
        case 2:  // FC 03 at an unmapped address: exception 02
          rq = read_request(3, 0x0100, 1);
          rp = exception_reply(3, 2);
          break;
        default: {  // FC 03, 10 registers
          rq = read_request(3, addr, 10);
          std::vector<uint16_t> w(10, tid);
          rp = read_registers_reply(3, w);
        }
      }
      packet(c.data(true, mbap_frame(tid, 1, rq)), 1000);
      packet(c.data(false, mbap_frame(tid, 1, rp)), 300);
      ++requests;
    }
    packet(c.fin(true), 10);
    packet(c.fin(false), 10);
  }
  std::fclose(f);
  return requests;
}

struct Timed {
  double seconds = 0;
  double cpu_seconds = 0;  // user + system: what a busy machine's other work does not inflate
  long max_rss_kb = 0;
  int status = -1;
};

Timed run(const std::vector<std::string>& argv) {
  auto t0 = std::chrono::steady_clock::now();
  pid_t pid = fork();
  if (pid == 0) {
    FILE* null = std::fopen("/dev/null", "w");
    if (null) {
      dup2(fileno(null), 1);
      dup2(fileno(null), 2);
    }
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    execvp(args[0], args.data());
    _exit(127);
  }
  Timed r;
  rusage ru{};
  int st = 0;
  wait4(pid, &st, 0, &ru);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.max_rss_kb = ru.ru_maxrss;
  r.cpu_seconds = double(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) + double(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) / 1e6;
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  std::string mbconform = "build/bin/mbconform", keep;
  uint64_t mb = 64;
  bool tshark = true;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--mb" && i + 1 < argc) mb = std::strtoull(argv[++i], nullptr, 10);
    else if (a == "--no-tshark") tshark = false;
    else if (a == "--keep" && i + 1 < argc) keep = argv[++i];
    else if (a.rfind("--", 0) != 0) mbconform = a;
    else {
      fmt::print(stderr, "usage: mbc_bench_capture [MBCONFORM] [--mb N] [--no-tshark] [--keep FILE]\n");
      return 2;
    }
  }
  auto dir = std::filesystem::temp_directory_path() / ("mbc_bench_capture." + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  std::string file = keep.empty() ? (dir / "bench.pcapng").string() : keep;
  uint64_t requests = generate(file, mb);
  auto size = std::filesystem::file_size(file);
  fmt::print("capture: {:.1f} MB, {} Modbus/TCP requests and replies\n", double(size) / 1e6, requests);

  Timed mine = run({mbconform, "check-capture", file, "--device", "modbus-standard", "--out", (dir / "out").string()});
  fmt::print("check-capture: {:.2f} s wall, {:.2f} s CPU ({:.1f} MB/s of CPU), peak RSS {:.1f} MB, exit {}\n", mine.seconds,
             mine.cpu_seconds, double(size) / 1e6 / mine.cpu_seconds, mine.max_rss_kb / 1024.0, mine.status);
  bool ok = mine.status == 0 || mine.status == 1;
  if (!ok) fmt::print("check-capture did not run (exit {})\n", mine.status);
  bool rss_ok = mine.max_rss_kb < 200 * 1024;
  fmt::print("memory: {:.1f} MB peak, target < 200 MB: {}\n", mine.max_rss_kb / 1024.0, rss_ok ? "met" : "NOT met");
  bool speed_ok = true;
  if (tshark) {
    Timed ts = run({"tshark", "-n", "-r", file, "-Y", "mbtcp"});
    fmt::print("tshark -r FILE -Y mbtcp: {:.2f} s wall, {:.2f} s CPU ({:.1f} MB/s of CPU), peak RSS {:.1f} MB, exit {}\n",
               ts.seconds, ts.cpu_seconds, double(size) / 1e6 / ts.cpu_seconds, ts.max_rss_kb / 1024.0, ts.status);
    // The target is judged on CPU time: on a shared machine the wall clock
    // measures the other work too (both ratios are printed).
    double ratio = ts.cpu_seconds / mine.cpu_seconds, wall_ratio = ts.seconds / mine.seconds;
    speed_ok = ratio >= 5.0;
    fmt::print("ratio: check-capture is {:.1f}x tshark's speed in CPU time (target >= 5x): {}; {:.1f}x in wall time\n",
               ratio, speed_ok ? "met" : "NOT met", wall_ratio);
  }
  std::filesystem::remove_all(dir);
  return ok && rss_ok && speed_ok ? 0 : 1;
}
