// Fuzz harness throughput and coverage, each beside a baseline measured in
// the same run (absolute numbers depend on the machine; the ratios travel):
//
//   1. in-process executions per second of the single-frame (device_fuzzer)
//      and session (session_fuzzer) harnesses against the baseline
//      libmodbus_reply_fuzzer (modbus_reply on the equivalent mapping), each
//      fed its seed corpus and deterministic one-byte mutations of it. The
//      harness bodies are the ones in fuzz/, compiled in under other names
//      (fuzz/CMakeLists.txt), so this runs in any build, gcc included.
//   3. with --fuzzers DIR (the bin/ of a -DMBCONFORM_FUZZ=ON build): every
//      libFuzzer binary run for a fixed -runs=N from its seeds, its exec/s
//      and the edges it reached ("cov:" in libFuzzer's last status line).
//
//   2. with --mbconform BIN (default build/bin/mbconform when it exists): the
//      black-box `mbconform fuzz` against `mbconform serve`, frames per
//      second over TCP loopback pipelined (--pipeline 16) beside one exchange
//      at a time (--pipeline 1), and on a pty at 115200 baud (serve
//      --line-rate) its wall time against two bounds measured in the same
//      run: the wire-time bound of the frames it sent (each frame's
//      characters plus t3.5, MB-SL v1.02 §2.5.1.1; a silence counts only its
//      request), and that bound plus, for each exchange that got no reply,
//      the p99 reply latency of the run (the least a master can wait before
//      it calls a silence, as bench/bench_run.cpp adds for the runner).
//      Targets: >= 1000 frames/s over TCP; <= 1.2x the wire-time bound on
//      the pty. --pty-runs N repeats the pty run (the ratios vary with load).
//
// Usage (from the source root): build/bin/mbc_fuzz_bench [--seconds S] [--fuzzers build-fuzz/bin] [--runs N]
//                               [--mbconform BIN] [--device ID] [--pty-runs N]
#include <signal.h>
#include <sys/wait.h>

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <regex>
#include <string>
#include <vector>

extern "C" int mbc_bench_device_one_input(const uint8_t*, size_t);
extern "C" int mbc_bench_session_one_input(const uint8_t*, size_t);
extern "C" int mbc_bench_libmodbus_one_input(const uint8_t*, size_t);

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using Input = std::vector<uint8_t>;
using Harness = int (*)(const uint8_t*, size_t);

std::vector<Input> load_dir(const fs::path& dir) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (e.is_regular_file()) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  std::vector<Input> out;
  for (const auto& f : files) {
    std::ifstream in(f, std::ios::binary);
    out.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  return out;
}

// The seeds, then each seed with one byte changed (xorshift, fixed seed): the
// kind of input a fuzzer spends most of its time on.
std::vector<Input> workload(const std::vector<Input>& seeds, size_t mutants_per_seed) {
  std::vector<Input> w = seeds;
  uint64_t x = 0x9E3779B97F4A7C15ull;
  auto next = [&] {
    x ^= x << 13, x ^= x >> 7, x ^= x << 17;
    return x;
  };
  for (const auto& s : seeds)
    for (size_t i = 0; i < mutants_per_seed && !s.empty(); ++i) {
      Input m = s;
      m[next() % m.size()] = uint8_t(next());
      w.push_back(std::move(m));
    }
  return w;
}

// Frames in a session_fuzzer input (records as fuzz/input_format.h reads
// them: op % 4 = 0/1 a frame [n][n bytes], 2 advance [2 bytes], 3 power cycle).
size_t session_frames(const Input& in) {
  size_t at = 2, frames = 0;
  for (int steps = 0; at < in.size() && steps < 256; ++steps) {
    uint8_t op = in[at++] % 4;
    if (op <= 1) {
      if (at >= in.size()) break;
      at += 1 + std::min<size_t>(in[at], in.size() - at - 1);
      ++frames;
    } else if (op == 2) {
      at += 2;
    }
  }
  return frames;
}

double execs_per_second(Harness h, const std::vector<Input>& inputs, double seconds) {
  if (inputs.empty()) return 0;
  long n = 0;
  auto t0 = Clock::now();
  auto end = t0 + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
  do {
    for (const auto& in : inputs) h(in.data(), in.size());
    n += long(inputs.size());
  } while (Clock::now() < end);
  return double(n) / std::chrono::duration<double>(Clock::now() - t0).count();
}

struct FuzzerRun {
  bool ok = false;
  long cov = -1, ft = -1;
  double seconds = 0;  // wall time of the whole run, start-up included
};

// One libFuzzer binary for exactly `runs` executions from its seeds.
FuzzerRun run_fuzzer(const fs::path& bin, const fs::path& seeds, const fs::path& dict, long runs) {
  fs::path work = fs::temp_directory_path() / ("mbc_fuzz_bench_" + bin.filename().string() + std::to_string(getpid()));
  fs::remove_all(work);
  fs::create_directories(work);
  fs::path log = work / "log";
  std::string cmd = bin.string() + " -seed=1 -runs=" + std::to_string(runs) + " -max_len=512 -print_final_stats=1";
  if (fs::exists(dict)) cmd += " -dict=" + dict.string();
  cmd += " " + work.string() + " " + seeds.string() + " > " + log.string() + " 2>&1";
  auto t0 = Clock::now();
  int rc = std::system(cmd.c_str());
  FuzzerRun r;
  r.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  r.ok = rc == 0;
  std::ifstream in(log);
  std::string line;
  // The last status line: "#20000 DONE cov: 7123 ft: 9042 corp: ...".
  std::regex status(R"(cov: (\d+) ft: (\d+))");
  std::smatch m;
  while (std::getline(in, line))
    if (std::regex_search(line, m, status)) r.cov = std::stol(m[1]), r.ft = std::stol(m[2]);
  fs::remove_all(work);
  return r;
}

// `mbconform serve --device ID <endpoint...>` in the background; stopped with SIGTERM.
struct Serve {
  pid_t pid = -1;
  std::string listening;  // the address of its first "listening" line
  Serve(const std::string& exe, std::vector<std::string> args) {
    int p[2];
    if (pipe(p) != 0) return;
    pid = fork();
    if (pid == 0) {
      dup2(p[1], 1);
      close(p[0]);
      close(p[1]);
      std::vector<char*> argv{const_cast<char*>(exe.c_str()), const_cast<char*>("serve")};
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      execv(exe.c_str(), argv.data());
      _exit(127);
    }
    close(p[1]);
    FILE* f = fdopen(p[0], "r");
    char line[512];
    if (fgets(line, sizeof line, f)) {
      std::string l = line;
      auto sp = l.rfind(' ');
      if (l.rfind("listening ", 0) == 0 && sp != std::string::npos) listening = l.substr(sp + 1, l.find_last_not_of("\r\n") - sp);
    }
    fclose(f);
  }
  ~Serve() {
    if (pid > 0) {
      kill(pid, SIGTERM);
      waitpid(pid, nullptr, 0);
    }
  }
};

// Runs a shell command and returns its stdout.
std::string capture(const std::string& cmd) {
  std::string out;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return out;
  char buf[4096];
  for (size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
  pclose(p);
  return out;
}

struct FuzzRun {
  double frames_per_second = -1, wire_ratio = -1, silence_ratio = -1, p99_ms = -1;
  long exchanges = -1, silent = -1;
  std::string summary;
};

FuzzRun black_box(const std::string& exe, const std::string& target, const std::string& device, double seconds, int pipeline) {
  fs::path out = fs::temp_directory_path() / ("mbc_fuzz_bench_out" + std::to_string(getpid()));
  fs::remove_all(out);
  std::string cmd = exe + " fuzz --target '" + target + "' --device " + device + " --duration " +
                    std::to_string(int(seconds * 1000)) + "ms --seed 1 --pipeline " + std::to_string(pipeline) + " --out " +
                    out.string() + " 2>&1";
  std::string text = capture(cmd);
  fs::remove_all(out);
  FuzzRun r;
  std::smatch m;
  if (std::regex_search(text, m, std::regex(R"(\((\d+) frames/s)"))) r.frames_per_second = std::stod(m[1]);
  if (std::regex_search(text, m, std::regex(R"(baud: ([0-9.]+)x)"))) r.wire_ratio = std::stod(m[1]);
  if (std::regex_search(text, m, std::regex(R"((\d+) exchanges \((\d+) silent\))")))
    r.exchanges = std::stol(m[1]), r.silent = std::stol(m[2]);
  if (std::regex_search(text, m, std::regex(R"(p99 reply latency \(([0-9.]+) ms\): a bound of [0-9.]+ s: ([0-9.]+)x)")))
    r.p99_ms = std::stod(m[1]), r.silence_ratio = std::stod(m[2]);
  auto nl = text.find_last_of('\n', text.size() >= 2 ? text.size() - 2 : 0);
  r.summary = text.substr(nl == std::string::npos ? 0 : nl + 1);
  if (!r.summary.empty() && r.summary.back() == '\n') r.summary.pop_back();
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 3;
  long runs = 20000;
  fs::path fuzzers;
  std::string mbconform = fs::exists("build/bin/mbconform") ? "build/bin/mbconform" : "";
  std::string fuzz_device = "hsc60";
  int pty_runs = 1;
  fs::path src = MBCONFORM_SOURCE_DIR;
  for (int i = 1; i < argc; ++i) {
    std::string a = argv[i];
    if (a == "--seconds" && i + 1 < argc) seconds = std::atof(argv[++i]);
    else if (a == "--runs" && i + 1 < argc) runs = std::atol(argv[++i]);
    else if (a == "--fuzzers" && i + 1 < argc) fuzzers = argv[++i];
    else if (a == "--mbconform" && i + 1 < argc) mbconform = argv[++i];
    else if (a == "--device" && i + 1 < argc) fuzz_device = argv[++i];
    else if (a == "--pty-runs" && i + 1 < argc) pty_runs = std::max(1, std::atoi(argv[++i]));
    else {
      std::fprintf(stderr, "usage: mbc_fuzz_bench [--seconds S] [--fuzzers DIR] [--runs N] [--mbconform BIN] [--device ID] "
                           "[--pty-runs N]\n");
      return 2;
    }
  }
  fs::path corpus = src / "corpus";
  auto device = workload(load_dir(corpus / "device"), 8);
  auto session = workload(load_dir(corpus / "session"), 8);
  auto baseline_inputs = workload(load_dir(corpus / "differential"), 8);
  if (device.empty() || session.empty() || baseline_inputs.empty()) {
    std::fprintf(stderr, "mbc_fuzz_bench: no seeds under %s (run from the source root)\n", corpus.c_str());
    return 2;
  }
  std::printf("1. in-process harness executions per second (%.0f s each, seeds + 8 one-byte mutants per seed)\n", seconds);
  double base = execs_per_second(mbc_bench_libmodbus_one_input, baseline_inputs, seconds);
  double dev = execs_per_second(mbc_bench_device_one_input, device, seconds);
  double ses = execs_per_second(mbc_bench_session_one_input, session, seconds);
  std::printf("   %-34s %12.0f exec/s  (baseline)\n", "libmodbus_reply (modbus_reply)", base);
  std::printf("   %-34s %12.0f exec/s  %.2fx baseline\n", "device (one frame, 5 devices)", dev, dev / base);
  double frames = 0;
  for (const auto& in : session) frames += double(session_frames(in));
  frames /= double(session.size());
  std::printf("   %-34s %12.0f exec/s  %.2fx baseline  (%.0f frames per input: %.0f frames/s, %.2fx)\n",
              "session (frames + time + power)", ses, ses / base, frames, ses * frames, ses * frames / base);
  int status = 0;
  if (mbconform.empty()) {
    std::printf("2. black-box fuzzer: skipped (give --mbconform build/bin/mbconform)\n");
  } else {
    double fuzz_seconds = std::max(seconds, 5.0);
    std::printf("2. black-box `mbconform fuzz` against `mbconform serve --device %s`, %.0f s each, seed 1\n", fuzz_device.c_str(),
                fuzz_seconds);
    {
      Serve serve(mbconform, {"--device", fuzz_device + "@1", "--tcp", "127.0.0.1:0"});
      std::string uri = "tcp://" + serve.listening + "?unit=1";
      FuzzRun seq = black_box(mbconform, uri, fuzz_device, fuzz_seconds, 1);
      FuzzRun pip = black_box(mbconform, uri, fuzz_device, fuzz_seconds, 16);
      std::printf("   %-34s %12.0f frames/s  (one exchange at a time)\n", "tcp loopback, --pipeline 1", seq.frames_per_second);
      std::printf("   %-34s %12.0f frames/s  %.2fx  target >= 1000 frames/s: %s\n", "tcp loopback, --pipeline 16",
                  pip.frames_per_second, seq.frames_per_second > 0 ? pip.frames_per_second / seq.frames_per_second : 0,
                  pip.frames_per_second >= 1000 ? "met" : "NOT met");
      if (pip.frames_per_second < 1000) std::printf("     %s\n", pip.summary.c_str());
    }
    {
      fs::path pty = fs::temp_directory_path() / ("mbc_fuzz_bench_pty" + std::to_string(getpid()));
      Serve serve(mbconform, {"--device", fuzz_device + "@1", "--pty", pty.string(), "--baud", "115200", "--line-rate", "115200"});
      std::printf("   pty 115200 baud, line rate: wire-only = wall / the wire-time bound (every frame's characters + t3.5;\n"
                  "   a silence counts its request only); with silences = wall / (that bound + each silent exchange x the\n"
                  "   run's p99 reply latency)\n");
      for (int k = 0; k < pty_runs; ++k) {
        FuzzRun rtu = black_box(mbconform, "rtu://" + pty.string() + "?baud=115200&parity=N&unit=1", fuzz_device, fuzz_seconds, 1);
        std::printf("   %-22s %5.0f frames/s, %ld exchanges (%ld silent), p99 reply %.2f ms: wire-only %.2fx, "
                    "with silences %.2fx; target wire-only <= 1.2x: %s\n",
                    "pty 115200, line rate", rtu.frames_per_second, rtu.exchanges, rtu.silent, rtu.p99_ms, rtu.wire_ratio,
                    rtu.silence_ratio, rtu.wire_ratio > 0 && rtu.wire_ratio <= 1.2 ? "met" : "NOT met");
        if (rtu.wire_ratio < 0) std::printf("     %s\n", rtu.summary.c_str());
      }
    }
  }
  if (fuzzers.empty()) {
    std::printf("3. libFuzzer runs: skipped (give --fuzzers build-fuzz/bin)\n");
    return status;
  }
  std::printf("3. libFuzzer, -runs=%ld -seed=1 from the seeds: edges (cov) and features (ft) reached;\n"
              "   exec/s over the whole run's wall time, start-up and seed loading included\n", runs);
  const char* harnesses[] = {"libmodbus_reply", "device", "session", "differential", "rtu_frame", "reply_parser", "spec_loader"};
  double base_execs = -1;
  int failed = 0;
  for (const char* h : harnesses) {
    std::string seeds = std::string(h) == "libmodbus_reply" ? "differential" : h;
    FuzzerRun r = run_fuzzer(fuzzers / (std::string(h) + "_fuzzer"), corpus / seeds, src / "fuzz" / (seeds + "_fuzzer.dict"), runs);
    double eps = r.seconds > 0 ? double(runs) / r.seconds : 0;
    if (std::string(h) == "libmodbus_reply") base_execs = eps;
    failed += !r.ok;
    std::printf("   %-16s cov %6ld  ft %6ld  %9.0f exec/s", h, r.cov, r.ft, eps);
    if (base_execs > 0 && std::string(h) != "libmodbus_reply") std::printf("  %.2fx baseline", eps / base_execs);
    std::printf("%s\n", r.ok ? "" : "  (exited non-zero: a finding?)");
  }
  return failed ? 1 : 0;
}
