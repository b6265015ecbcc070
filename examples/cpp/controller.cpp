// A C++ controller loop reading a layer periodically at 1 kHz: every
// millisecond (absolute time, no drift) it takes the newest frame of a
// layer, computes a "pressure" command from it, and at the end prints how
// late its wake-ups were and how many frames were fresh.
//
//   skin run examples/demo.toml &
//   ./controller default virtual-0 5 1000   # skin, layer, seconds, Hz
//
// Build: c++ -std=c++17 controller.cpp $(pkg-config --cflags --libs skinware) -o controller
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

#include <skinware.hpp>

int main(int argc, char** argv) try {
  const std::string skin = argc > 1 ? argv[1] : "default";
  const std::string layer = argc > 2 ? argv[2] : "virtual-0";
  const double seconds = argc > 3 ? std::stod(argv[3]) : 5.0;
  const double hz = argc > 4 ? std::stod(argv[4]) : 1000.0;
  const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / hz));

  skinware::reader reader(skin, layer);
  skinware::topology topology = reader.layer_topology();
  std::printf("%s/%s: %zu sensors, controller at %.0f Hz for %.1f s\n", skin.c_str(), layer.c_str(),
              topology.sensors(), hz, seconds);

  const auto ticks = static_cast<std::size_t>(seconds * hz);
  std::vector<std::uint64_t> lateness;
  lateness.reserve(ticks);
  std::size_t fresh = 0, faulted = 0;
  double command = 0.0;
  auto frames = reader.periodic<std::uint16_t>(period);
  for (const auto& read : frames) {
    // The control law: a first-order filter of the mean response.
    std::uint64_t sum = 0;
    for (std::uint16_t value : read.values) sum += value;
    command += 0.1 * (static_cast<double>(sum) / read.values.size() - command);
    lateness.push_back(read.tick.lateness_ns);
    fresh += read.info.fresh ? 1 : 0;
    faulted += (read.info.status & SKINWARE_FRAME_FAULT) ? 1 : 0;
    if (lateness.size() >= ticks) break;
  }

  std::sort(lateness.begin(), lateness.end());
  auto at = [&](double q) { return lateness.empty() ? 0 : lateness[static_cast<std::size_t>(q * (lateness.size() - 1))]; };
  std::printf("ticks %zu, fresh frames %zu, faulted %zu, last command %.1f\n", lateness.size(), fresh,
              faulted, command);
  std::printf("wake-up lateness: p50 %.1f us, p99 %.1f us, max %.1f us\n", at(0.5) / 1e3, at(0.99) / 1e3,
              at(1.0) / 1e3);
  const skinware_reader_stats stats = reader.stats();
  std::printf("reads %llu, mean copy %.1f us\n", static_cast<unsigned long long>(stats.reads),
              stats.read_ns_mean / 1e3);
  return 0;
} catch (const skinware::error& e) {
  std::fprintf(stderr, "controller: %s\n", e.what());
  return 1;
}
