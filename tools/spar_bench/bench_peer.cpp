#include "tools/spar_bench/bench_peer.h"

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "spar/error.h"
#include "tools/common/shell_quote.h"

namespace spar::bench {

PeerTimes runPeer(const std::vector<BenchCase>& cases, int repeats) {
  namespace fs = std::filesystem;
  nlohmann::json job = {{"repeat", repeats}, {"cases", nlohmann::json::array()}};
  for (const auto& c : cases) job["cases"].push_back(c.peer);
  const std::string stem = "spar-bench-peer-" + std::to_string(::getpid());
  const fs::path in = fs::temp_directory_path() / (stem + "-in.json");
  const fs::path out = fs::temp_directory_path() / (stem + "-out.json");
  std::ofstream(in) << job.dump() << "\n";
  const std::string script = std::string(SPAR_SOURCE_DIR) + "/scripts/compare/bench_peer.py";
  const std::string cmd = "env -u OPENBLAS_CORETYPE -u OPENBLAS_L2_SIZE " + shellQuote(SPAR_PYTHON) + " " + shellQuote(script) +
                          " " + shellQuote(in.string()) + " " + shellQuote(out.string());
  const int code = std::system(cmd.c_str());
  fs::remove(in);
  std::ifstream result(out);
  if (code != 0 || !result) {
    fs::remove(out);
    throw Error("the CPU peer failed (it needs Debian's python3-numpy and python3-torch): " + cmd);
  }
  const nlohmann::json doc = nlohmann::json::parse(result);
  result.close();
  fs::remove(out);
  PeerTimes t;
  t.peer = doc.at("peer").get<std::string>();
  for (const auto& ms : doc.at("ms")) t.ms.push_back(ms.is_null() ? std::nullopt : std::optional<double>(ms.get<double>()));
  if (t.ms.size() != cases.size()) throw Error("the CPU peer returned " + std::to_string(t.ms.size()) + " times for " +
                                               std::to_string(cases.size()) + " cases");
  return t;
}

}  // namespace spar::bench
