// A seeded mutation runner: main() for a libFuzzer-style target (LLVMFuzzerTestOneInput) when the
// build has no libFuzzer (gcc, CI). It runs every seed of the corpus, then a fixed number of
// mutants of them (or until a time limit), deterministic for a given --seed. No coverage
// feedback: the mutations know the safetensors framing instead (8-byte header length, JSON
// numbers and tokens), so most mutants get past the first checks.
//
//   spar_reader_fuzz [--execs N] [--seconds S] [--seed K] [--findings DIR] CORPUS_DIR_OR_FILE...
//
// N defaults to 100000; --execs 0 runs the given files only (to replay a finding). A finding (an exception escaping the target, a crash signal, an abort, a run over
// 10 s) writes the input to DIR/finding-<seed>-<exec>.bin and ends with a one-line message
// naming it and exit status 1.
#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

namespace {

namespace fs = std::filesystem;
using Bytes = std::vector<uint8_t>;

constexpr unsigned kHangSeconds = 10;
constexpr size_t kMaxInput = 1 << 20;

// What the signal handler needs, set before every execution (a handler may only use these and
// async-signal-safe calls).
const Bytes* gCurrent = nullptr;
char gFindingPath[4096];

void writeAll(int fd, const void* p, size_t n) {
  const char* c = static_cast<const char*>(p);
  while (n) {
    ssize_t k = ::write(fd, c, n);
    if (k <= 0) return;
    c += k;
    n -= static_cast<size_t>(k);
  }
}

void saveCurrent() {
  int fd = ::open(gFindingPath, O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) return;
  if (gCurrent) writeAll(fd, gCurrent->data(), gCurrent->size());
  ::close(fd);
}

void onSignal(int sig) {
  saveCurrent();
  const char* what = sig == SIGALRM ? "hang (over 10 s)" : strsignal(sig);
  const char* parts[] = {"spar_reader_fuzz: FINDING: ", what, " on the input saved as ", gFindingPath, "\n"};
  for (const char* s : parts) writeAll(2, s, std::strlen(s));
  signal(sig, SIG_DFL);
  if (sig == SIGALRM) _exit(1);
  raise(sig);
}

Bytes readFile(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// --- mutations ------------------------------------------------------------------------------

struct Mutator {
  std::mt19937_64 rng;
  const std::vector<Bytes>& seeds;

  size_t below(size_t n) { return n ? static_cast<size_t>(rng() % n) : 0; }

  static uint64_t headerLength(const Bytes& b) {
    uint64_t n = 0;
    if (b.size() >= 8) std::memcpy(&n, b.data(), 8);
    return n;
  }
  static void setHeaderLength(Bytes& b, uint64_t n) {
    if (b.size() >= 8) std::memcpy(b.data(), &n, 8);
  }
  // Where the JSON header ends (clamped to the input).
  static size_t headerEnd(const Bytes& b) {
    const uint64_t n = headerLength(b);
    return n > b.size() - std::min<size_t>(b.size(), 8) ? b.size() : static_cast<size_t>(8 + n);
  }

  // An edit of `delta` bytes at `pos`: usually keep the stored header length true, so the JSON
  // stays framed and the mutant reaches the checks after the parse.
  void resized(Bytes& b, size_t pos, int64_t delta, uint64_t oldLength) {
    if (pos >= 8 && pos < 8 + oldLength && below(10) < 8) setHeaderLength(b, oldLength + delta);
  }

  void insert(Bytes& b, size_t pos, const Bytes& what) {
    const uint64_t len = headerLength(b);
    b.insert(b.begin() + pos, what.begin(), what.end());
    resized(b, pos, static_cast<int64_t>(what.size()), len);
  }
  void erase(Bytes& b, size_t pos, size_t n) {
    const uint64_t len = headerLength(b);
    b.erase(b.begin() + pos, b.begin() + pos + n);
    resized(b, pos, -static_cast<int64_t>(n), len);
  }

  static Bytes str(const char* s) { return Bytes(s, s + std::strlen(s)); }

  // JSON numbers at the edges of what the reader must handle (sizes, offsets, config values).
  Bytes interestingNumber() {
    static const char* kNumbers[] = {"0", "1", "-1", "2", "3", "7", "8", "15", "16", "17", "64", "255", "256",
                                     "1048576", "1048577", "2147483647", "2147483648", "4294967295",
                                     "4294967296", "9223372036854775807", "9223372036854775808",
                                     "18446744073709551615", "18446744073709551616", "1e308", "1e309",
                                     "-1e308", "0.5", "1.0", "-0", "1e-320", "3.4e38", "3.5e38", "1e30"};
    return str(kNumbers[below(std::size(kNumbers))]);
  }
  Bytes token() {
    static const char* kTokens[] = {"\"F32\"", "\"F16\"", "\"I32\"", "\"I64\"", "\"U8\"", "\"BF16\"", "\"dtype\"",
                                    "\"shape\"", "\"data_offsets\"", "\"__metadata__\"", "[]", "{}", "[0,0]",
                                    "null", "true", "false", "\"\"", ",", ":", "\\\"", "\\u0000", "\"x\":",
                                    "{\"dtype\":\"F32\",\"shape\":[1],\"data_offsets\":[0,4]}"};
    return str(kTokens[below(std::size(kTokens))]);
  }

  // One edit; the kinds are equally likely.
  void once(Bytes& b) {
    if (b.empty()) b.push_back(0);
    const size_t pos = below(b.size());
    switch (below(10)) {
      case 0:  // flip a bit
        b[pos] ^= static_cast<uint8_t>(1u << below(8));
        break;
      case 1: {  // an interesting byte
        static const uint8_t kBytes[] = {0, 1, 0x7f, 0x80, 0xff, '"', '{', '}', '[', ']', ',', ':', '0', '9', '-', 'e', '\\'};
        b[pos] = kBytes[below(sizeof kBytes)];
        break;
      }
      case 2: {  // insert random bytes
        Bytes r(1 + below(8));
        for (auto& x : r) x = static_cast<uint8_t>(rng());
        insert(b, pos, r);
        break;
      }
      case 3:
        insert(b, pos, token());
        break;
      case 4:  // delete up to 64 bytes
        erase(b, pos, 1 + below(std::min<size_t>(b.size() - pos, 64)));
        break;
      case 5: {  // copy a chunk elsewhere (duplicates keys, tensors, brackets)
        const size_t from = below(b.size()), n = 1 + below(std::min<size_t>(b.size() - from, 128));
        insert(b, pos, Bytes(b.begin() + from, b.begin() + from + n));
        break;
      }
      case 6:  // truncate
        b.resize(below(b.size() + 1));
        break;
      case 7: {  // replace a number of the header by an interesting one
        const size_t end = headerEnd(b);
        size_t p = pos < 8 ? 8 : pos;
        while (p < end && !(b[p] >= '0' && b[p] <= '9')) ++p;
        if (p >= end) break;
        size_t q = p;
        while (q < end && (std::isdigit(b[q]) || b[q] == '.' || b[q] == 'e' || b[q] == '-' || b[q] == '+')) ++q;
        erase(b, p, q - p);
        insert(b, p, interestingNumber());
        break;
      }
      case 8: {  // a new stored header length: off by a little, or anything
        const uint64_t n = headerLength(b);
        const int64_t deltas[] = {-1, 1, -8, 8, static_cast<int64_t>(b.size()) - 8 - static_cast<int64_t>(n)};
        setHeaderLength(b, below(4) ? n + deltas[below(std::size(deltas))] : rng());
        break;
      }
      default: {  // splice in a piece of another seed
        const Bytes& o = seeds[below(seeds.size())];
        if (o.empty()) break;
        const size_t from = below(o.size()), n = 1 + below(std::min<size_t>(o.size() - from, 256));
        const size_t m = std::min(n, b.size() - pos);
        std::copy(o.begin() + from, o.begin() + from + m, b.begin() + pos);
        break;
      }
    }
    if (b.size() > kMaxInput) b.resize(kMaxInput);
  }

  Bytes mutant() {
    Bytes b = seeds[below(seeds.size())];
    for (size_t k = 1 + below(4); k; --k) once(b);
    return b;
  }
};

[[noreturn]] void usage(const char* why) {
  std::fprintf(stderr,
               "spar_reader_fuzz: %s\nusage: spar_reader_fuzz [--execs N] [--seconds S] [--seed K] [--findings DIR] "
               "CORPUS_DIR_OR_FILE...\n",
               why);
  std::exit(2);
}

}  // namespace

int main(int argc, char** argv) {
  uint64_t execs = 100000;
  double seconds = 0;  // 0: no time limit
  uint64_t seed = 1;
  fs::path findings = ".";
  std::vector<Bytes> seeds;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) usage(("missing value after " + a).c_str());
      return argv[++i];
    };
    if (a == "--execs") execs = std::strtoull(value(), nullptr, 10);
    else if (a == "--seconds") seconds = std::strtod(value(), nullptr);
    else if (a == "--seed") seed = std::strtoull(value(), nullptr, 10);
    else if (a == "--findings") findings = value();
    else if (a.rfind("--", 0) == 0) usage(("unknown option " + a).c_str());
    else if (fs::is_directory(a)) {
      std::vector<fs::path> files;  // sorted: the run must not depend on directory order
      for (const auto& e : fs::directory_iterator(a))
        if (e.is_regular_file()) files.push_back(e.path());
      std::sort(files.begin(), files.end());
      for (const auto& f : files) seeds.push_back(readFile(f));
    } else if (fs::is_regular_file(a)) seeds.push_back(readFile(a));
    else usage(("no such file or directory: " + a).c_str());
  }
  if (seeds.empty()) usage("no corpus files");

  for (int s : {SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGABRT, SIGALRM}) signal(s, onSignal);
  Mutator mutator{std::mt19937_64(seed), seeds};
  const auto start = std::chrono::steady_clock::now();
  const uint64_t total = seeds.size() + execs;
  uint64_t done = 0;
  for (; done < total; ++done) {
    if (seconds > 0 && (done & 255) == 0 &&
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() > seconds)
      break;
    const Bytes input = done < seeds.size() ? seeds[done] : mutator.mutant();
    gCurrent = &input;
    std::snprintf(gFindingPath, sizeof gFindingPath, "%s/finding-%llu-%llu.bin", findings.c_str(),
                  static_cast<unsigned long long>(seed), static_cast<unsigned long long>(done));
    alarm(kHangSeconds);
    try {
      LLVMFuzzerTestOneInput(input.data(), input.size());
    } catch (const std::exception& e) {
      saveCurrent();
      std::fprintf(stderr, "spar_reader_fuzz: FINDING: exception escaped: %s on the input saved as %s\n", e.what(),
                   gFindingPath);
      return 1;
    } catch (...) {
      saveCurrent();
      std::fprintf(stderr, "spar_reader_fuzz: FINDING: non-std exception escaped on the input saved as %s\n",
                   gFindingPath);
      return 1;
    }
  }
  alarm(0);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("spar_reader_fuzz: %llu executions (%zu seeds, seed %llu) in %.1f s, %.0f/s, 0 findings\n",
              static_cast<unsigned long long>(done), seeds.size(), static_cast<unsigned long long>(seed), s,
              s > 0 ? done / s : 0.0);
  return 0;
}
