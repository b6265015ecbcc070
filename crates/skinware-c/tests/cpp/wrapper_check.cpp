// The C++ wrapper's test program, driven by crates/skin/tests/integration/c_api.rs
// against `skin run`'s virtual skin:
//
//   wrapper_check periodic SKIN LAYER N HZ   N periodic frames: "seq SEQ CHECKSUM" lines
//   wrapper_check exceptions SKIN LAYER      RAII, exceptions, ranges, stop, writer round trip
#include <atomic>
#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "skinware.hpp"

using namespace std::chrono_literals;

static int failures = 0;
#define EXPECT(condition, what)                                                        \
  do {                                                                                 \
    if (!(condition)) {                                                                \
      std::fprintf(stderr, "FAILED %s:%d: %s: %s\n", __FILE__, __LINE__, #condition, what); \
      failures++;                                                                      \
    }                                                                                  \
  } while (0)

// FNV-1a over the responses' little-endian bytes, as api_check.c and the Rust side.
static std::uint64_t checksum(skinware::span<const std::uint16_t> values) {
  std::uint64_t hash = 0xcbf29ce484222325ull;
  for (std::uint16_t value : values) {
    for (std::uint8_t byte : {static_cast<std::uint8_t>(value & 0xFF), static_cast<std::uint8_t>(value >> 8)}) {
      hash = (hash ^ byte) * 0x100000001b3ull;
    }
  }
  return hash;
}

template <class Exception, class Body>
static bool throws(Body body) {
  try {
    body();
  } catch (const Exception& e) {
    return std::strlen(e.what()) > 10;
  } catch (...) {
    return false;
  }
  return false;
}

static int periodic(const std::string& skin, const std::string& layer, long n, double hz) {
  skinware::reader reader(skin, layer);
  long printed = 0;
  for (const auto& read : reader.periodic<std::uint16_t>(std::chrono::nanoseconds(static_cast<long>(1e9 / hz)))) {
    if (read.info.fresh) {
      std::printf("seq %" PRIu64 " %" PRIu64 "\n", read.info.seq, checksum(read.values));
      if (++printed >= n) break;
    }
  }
  std::fflush(stdout);
  return 0;
}

static void exceptions(const std::string& skin, const std::string& layer) {
  EXPECT(throws<skinware::not_found>([] { skinware::reader("no_such_skin", "x"); }), "a missing skin");
  EXPECT(throws<skinware::schema_mismatch>([&] { skinware::reader::contacts(skin, layer); }), "a layer as contacts");
  EXPECT(throws<skinware::invalid_argument>([] { skinware::ticker(std::chrono::nanoseconds(0)); }), "period 0");
  static_assert(std::is_base_of<std::runtime_error, skinware::timeout_error>::value, "runtime_error");

  skinware::reader reader(skin, layer);
  auto frame = reader.buffer<std::uint16_t>();
  EXPECT(frame.size() == reader.describe().values, "buffer() sizes one value per sensor");
  std::vector<std::uint16_t> small(1);
  EXPECT(throws<skinware::invalid_argument>([&] { reader.latest(small); }), "a buffer too small");
  auto read = reader.wait_newer(frame, 2s);
  EXPECT(read.info.seq > 0 && read.values.size() == frame.size(), "wait_newer");
  skinware::topology topology = reader.layer_topology();
  auto uids = topology.uids();
  EXPECT(topology.index_of(uids.back()) == uids.size() - 1, "index_of the last uid");
  EXPECT(!topology.index_of(0xFFFFFFFFu).has_value(), "a missing uid is nullopt");

  // A frames() range ends when the reader is stopped from another thread.
  std::atomic<long> seen{0};
  std::thread stopper([&] {
    std::this_thread::sleep_for(300ms);
    reader.stop();
  });
  auto started = std::chrono::steady_clock::now();
  for (const auto& next : reader.frames<std::uint16_t>()) {
    (void)next;
    seen++;
  }
  stopper.join();
  EXPECT(seen > 0, "frames() saw frames before the stop");
  EXPECT(std::chrono::steady_clock::now() - started < 2s, "stop() ended the range at once");
  EXPECT(throws<skinware::stopped>([&] { reader.wait_newer(frame, 1s); }), "a stopped reader");

  // A periodic range ends at once when it, or its reader, is stopped from
  // another thread: with 1 s ticks, the wait for the second tick is woken.
  for (bool through_reader : {false, true}) {
    skinware::reader slow(skin, layer);
    auto ticks = slow.periodic<std::uint16_t>(1s);
    std::thread stopper([&] {
      std::this_thread::sleep_for(300ms);
      if (through_reader) {
        slow.stop();
      } else {
        ticks.stop();
      }
    });
    auto began = std::chrono::steady_clock::now();
    long ticked = 0;
    for (const auto& next : ticks) {
      (void)next;
      ticked++;
    }
    stopper.join();
    EXPECT(ticked == 1, "one tick (the first is due at once) before the stop");
    EXPECT(std::chrono::steady_clock::now() - began < 800ms,
           through_reader ? "reader.stop() woke the periodic wait" : "the range's stop() woke the periodic wait");
  }

  // A move-only handle: the moved-from one is empty, the moved-to one works.
  skinware::reader first(skin, layer);
  skinware::reader second = std::move(first);
  EXPECT(first.get() == nullptr && second.get() != nullptr, "moved");
  second.latest(frame);

  // A writer and a reader in one program: what is published is what is read.
  skinware::topology layout = skinware::topology_builder("cpp_layer", "pressure", 0.0)
                                  .add_module(1, 1, {10, 11, 12})
                                  .add_module(1, 2, {13, 14})
                                  .build();
  EXPECT(layout.sensors() == 5, "5 sensors");
  skinware::writer writer(skin, "cpp_layer", layout);
  skinware::reader mine(skin, "cpp_layer");
  std::vector<std::uint16_t> values{1, 2, 3, 4, 5};
  std::uint64_t seq = writer.publish(values);
  std::vector<std::uint16_t> got(5);
  auto mine_read = mine.latest(got);
  EXPECT(mine_read.info.seq == seq && got == values, "round trip");
  EXPECT(throws<skinware::invalid_argument>([&] { writer.schedule(); }), "a sporadic writer has no schedule");
  bool listed = false;
  for (const auto& channel : skinware::list_channels(skin)) listed |= channel.name == "cpp_layer" && channel.sensors == 5;
  EXPECT(listed, "list_channels has cpp_layer");

  skinware::geometry geometry(skin);
  EXPECT(geometry.positions().size() == 3 * geometry.sensors(), "3 floats per sensor");
  if (geometry.summary().regions > 0) {
    skinware_region region = geometry.region(0);
    EXPECT(geometry.region(std::string(region.name)).size() == region.sensor_count, "a region by name");
  }
  EXPECT(throws<skinware::not_found>([&] { geometry.region(std::string("no such region")); }), "a missing region");
  std::printf("wrapper ok\n");
}

int main(int argc, char** argv) try {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s periodic|exceptions SKIN LAYER [N HZ]\n", argv[0]);
    return 2;
  }
  std::string mode = argv[1], skin = argv[2], layer = argv[3];
  skinware::require_abi();
  if (mode == "periodic") return periodic(skin, layer, argc > 4 ? std::stol(argv[4]) : 10, argc > 5 ? std::stod(argv[5]) : 200.0);
  if (mode == "exceptions") exceptions(skin, layer);
  if (failures) std::fprintf(stderr, "%d expectations failed\n", failures);
  return failures != 0;
} catch (const skinware::error& e) {
  std::fprintf(stderr, "wrapper_check: %s\n", e.what());
  return 1;
}
