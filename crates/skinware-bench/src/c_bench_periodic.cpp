// `skin bench c`'s C++ side: a periodic reader at HZ through the C++
// wrapper's range, for SECONDS; prints each tick's wake-up lateness, ns.
//   c_bench_periodic SKIN LAYER HZ SECONDS
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <skinware.hpp>

int main(int argc, char** argv) try {
  if (argc < 5) {
    std::fprintf(stderr, "usage: c_bench_periodic SKIN LAYER HZ SECONDS\n");
    return 2;
  }
  const double hz = std::stod(argv[3]), seconds = std::stod(argv[4]);
  skinware::reader reader(argv[1], argv[2]);
  const auto ticks = static_cast<std::size_t>(hz * seconds);
  std::vector<std::uint64_t> lateness;
  lateness.reserve(ticks);
  std::uint64_t checksum = 0;
  for (const auto& read : reader.periodic<std::uint16_t>(std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / hz)))) {
    lateness.push_back(read.tick.lateness_ns);
    checksum += read.values[0];
    if (lateness.size() >= ticks) break;
  }
  for (std::uint64_t late : lateness) std::printf("%llu\n", static_cast<unsigned long long>(late));
  std::fprintf(stderr, "checksum %llu\n", static_cast<unsigned long long>(checksum));
  return 0;
} catch (const skinware::error& e) {
  std::fprintf(stderr, "c_bench_periodic: %s\n", e.what());
  return 1;
}
