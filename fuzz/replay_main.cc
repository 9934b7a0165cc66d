// A main for the fuzz targets in the ordinary build (g++, no libFuzzer): every file of the given
// corpus directories through LLVMFuzzerTestOneInput, then `mutations` deterministic mutations of
// each (bytes flipped, inserted, deleted, chunks spliced from another seed). CTest runs this in
// build/ and under ASan + UBSan in build-asan/, so a crash the seeds or their near neighbours
// find fails the test command in seconds; scripts/fuzz.sh runs the real fuzzer.
//   <target>_replay [--mutations N] DIR...
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace {

void Run(const std::string& bytes) {
  LLVMFuzzerTestOneInput(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size());
}

std::string Mutate(std::string s, const std::vector<std::string>& seeds, std::mt19937& rng) {
  auto pick = [&](std::size_t n) {
    return n == 0 ? 0 : std::uniform_int_distribution<std::size_t>(0, n - 1)(rng);
  };
  const int edits = 1 + static_cast<int>(pick(4));
  for (int e = 0; e < edits; ++e) {
    switch (pick(5)) {
      case 0:  // flip a byte
        if (!s.empty()) s[pick(s.size())] = static_cast<char>(rng());
        break;
      case 1:  // insert a byte that parsers care about
        s.insert(pick(s.size() + 1), 1, "\"=[]\n#.,-0e\xff"[pick(12)]);
        break;
      case 2:  // delete a run
        if (!s.empty()) {
          const std::size_t at = pick(s.size());
          s.erase(at, 1 + pick(std::min<std::size_t>(16, s.size() - at)));
        }
        break;
      case 3: {  // splice a chunk of another seed
        const std::string& o = seeds[pick(seeds.size())];
        if (!o.empty()) {
          const std::size_t from = pick(o.size());
          s.insert(pick(s.size() + 1), o.substr(from, 1 + pick(64)));
        }
        break;
      }
      default:  // truncate
        s.resize(pick(s.size() + 1));
    }
  }
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  int mutations = 200;
  std::vector<std::string> seeds;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--mutations") == 0 && i + 1 < argc) {
      mutations = std::atoi(argv[++i]);
      continue;
    }
    std::error_code ec;
    for (const auto& f : std::filesystem::directory_iterator(argv[i], ec)) {
      std::ifstream in(f.path(), std::ios::binary);
      seeds.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    if (ec) {
      std::fprintf(stderr, "%s: %s\n", argv[i], ec.message().c_str());
      return 2;
    }
  }
  if (seeds.empty()) {
    std::fprintf(stderr, "no seeds (usage: %s [--mutations N] DIR...)\n", argv[0]);
    return 2;
  }
  std::mt19937 rng(20261201);
  std::size_t runs = 0;
  for (const std::string& s : seeds) {
    Run(s);
    ++runs;
    for (int k = 0; k < mutations; ++k, ++runs) Run(Mutate(s, seeds, rng));
  }
  std::printf("%zu seeds, %zu inputs, no crash\n", seeds.size(), runs);
  return 0;
}
