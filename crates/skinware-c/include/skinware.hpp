// skinware.hpp: the C++17 wrapper of skinware's C API (skinware.h), header
// only. RAII handles (move-only), exceptions derived from std::runtime_error
// carrying the C API's status and message, spans over frames (skinware::span,
// pointer and size: C++17 has no std::span), and ranges for periodic and
// as-soon-as-available reads. docs/c.md is the guide.
//
//   skinware::reader layer("demo", "pressure");
//   std::vector<uint16_t> frame = layer.buffer<uint16_t>();
//   for (auto& read : layer.periodic<uint16_t>(std::chrono::milliseconds(1))) {
//     use(read.values, read.info.seq);  // 1 kHz, absolute time, no drift
//   }
#ifndef SKINWARE_HPP
#define SKINWARE_HPP

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <iterator>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "skinware.h"

namespace skinware {

// Any failure of the C API: its status and its message.
class error : public std::runtime_error {
 public:
  error(skinware_status status, const std::string& message)
      : std::runtime_error(message), status_(status) {}
  // The C API's status code.
  skinware_status status() const noexcept { return status_; }

 private:
  skinware_status status_;
};

// A bad argument: NULL, a wrong size, a closed handle, a value out of range.
struct invalid_argument : error { using error::error; };
// No such skin, channel, region, uid or index.
struct not_found : error { using error::error; };
// Nothing new before the timeout; the writer lives.
struct timeout_error : error { using error::error; };
// The writer is gone and no successor took its place.
struct writer_gone : error { using error::error; };
// The writer has not published its first frame yet.
struct no_frame_yet : error { using error::error; };
// The handle was stopped (reader::stop, ticker::stop, writer::stop).
struct stopped : error { using error::error; };
// The channel is not what was asked for (another schema, a layer as a service).
struct schema_mismatch : error { using error::error; };

// Throws the exception for `status`, with this thread's last error message.
[[noreturn]] inline void throw_status(skinware_status status) {
  std::string message = std::string(skinware_status_name(status)) + ": " + skinware_last_error();
  switch (status) {
    case SKINWARE_E_INVALID_ARGUMENT:
    case SKINWARE_E_BUFFER_TOO_SMALL: throw invalid_argument(status, message);
    case SKINWARE_E_NOT_FOUND: throw not_found(status, message);
    case SKINWARE_E_TIMEOUT: throw timeout_error(status, message);
    case SKINWARE_E_WRITER_GONE: throw writer_gone(status, message);
    case SKINWARE_E_NO_FRAME_YET: throw no_frame_yet(status, message);
    case SKINWARE_E_STOPPED: throw stopped(status, message);
    case SKINWARE_E_SCHEMA_MISMATCH: throw schema_mismatch(status, message);
    default: throw error(status, message);
  }
}

// Throws unless `status` is SKINWARE_OK.
inline void check(skinware_status status) {
  if (status != SKINWARE_OK) throw_status(status);
}

// Throws if the library loaded at run time has another ABI than this header.
inline void require_abi() {
  if (!skinware_abi_compatible()) {
    throw error(SKINWARE_E_INVALID_ARGUMENT,
                "libskinware implements C ABI " + std::to_string(skinware_abi_version()) +
                    ", this program was built against skinware.h of ABI " +
                    std::to_string(SKINWARE_ABI_VERSION) + "; rebuild it against the installed header");
  }
}

// A view of `size` contiguous values (C++17 has no std::span).
template <class T>
class span {
 public:
  span() = default;
  span(T* data, std::size_t size) : data_(data), size_(size) {}
  template <class U>
  span(std::vector<U>& values) : data_(values.data()), size_(values.size()) {}
  template <class U>
  span(const std::vector<U>& values) : data_(values.data()), size_(values.size()) {}
  T* data() const noexcept { return data_; }
  std::size_t size() const noexcept { return size_; }
  bool empty() const noexcept { return size_ == 0; }
  T* begin() const noexcept { return data_; }
  T* end() const noexcept { return data_ + size_; }
  T& operator[](std::size_t i) const noexcept { return data_[i]; }

 private:
  T* data_ = nullptr;
  std::size_t size_ = 0;
};

inline std::uint64_t to_ns(std::chrono::nanoseconds duration) {
  return duration.count() < 0 ? 0 : static_cast<std::uint64_t>(duration.count());
}

// A move-only owner of a C handle, freed by `Free`.
template <class Handle, skinware_status (*Free)(Handle*)>
class owned {
 public:
  owned() = default;
  explicit owned(Handle* handle) : handle_(handle) {}
  owned(const owned&) = delete;
  owned& operator=(const owned&) = delete;
  owned(owned&& other) noexcept : handle_(std::exchange(other.handle_, nullptr)) {}
  owned& operator=(owned&& other) noexcept {
    if (this != &other) {
      reset();
      handle_ = std::exchange(other.handle_, nullptr);
    }
    return *this;
  }
  ~owned() { reset(); }
  Handle* get() const noexcept { return handle_; }
  explicit operator bool() const noexcept { return handle_ != nullptr; }
  // Frees the handle now (destructors never throw: a failure is ignored).
  void reset() noexcept {
    if (handle_ != nullptr) (void)Free(std::exchange(handle_, nullptr));
  }

 private:
  Handle* handle_ = nullptr;
};

// A periodic schedule on absolute time (no drift).
class ticker {
 public:
  explicit ticker(std::chrono::nanoseconds period) {
    require_abi();
    skinware_ticker* handle = nullptr;
    check(skinware_ticker_new(to_ns(period), &handle));
    handle_ = owned_t(handle);
  }
  explicit ticker(skinware_ticker* adopted) : handle_(adopted) {}
  // Sleeps until the next deadline; throws `stopped` after stop().
  skinware_tick wait() {
    skinware_tick tick{};
    check(skinware_ticker_wait(handle_.get(), &tick));
    return tick;
  }
  // Wakes a wait blocked in another thread (it throws `stopped`).
  void stop() { check(skinware_ticker_stop(handle_.get())); }
  skinware_ticker* get() const noexcept { return handle_.get(); }

 private:
  using owned_t = owned<skinware_ticker, skinware_ticker_free>;
  owned_t handle_;
};

// A layer's topology: patches, modules, sensors.
class topology {
 public:
  explicit topology(skinware_topology* adopted) : handle_(adopted) {}
  // patches x modules_per_patch x sensors_per_module sensors, uids 0, 1, 2...
  static topology uniform(const std::string& name, const std::string& sensor_type, double rate_hz,
                          std::uint32_t patches, std::uint32_t modules_per_patch,
                          std::uint32_t sensors_per_module) {
    require_abi();
    skinware_topology* handle = nullptr;
    check(skinware_topology_uniform(name.c_str(), sensor_type.c_str(), rate_hz, patches,
                                    modules_per_patch, sensors_per_module, &handle));
    return topology(handle);
  }
  skinware_topology_summary summary() const {
    skinware_topology_summary summary{};
    check(skinware_topology_describe(handle_.get(), &summary));
    return summary;
  }
  std::size_t sensors() const { return summary().sensors; }
  skinware_sensor sensor(std::size_t index) const {
    skinware_sensor sensor{};
    check(skinware_topology_sensor(handle_.get(), index, &sensor));
    return sensor;
  }
  skinware_module module(std::size_t index) const {
    skinware_module module{};
    check(skinware_topology_module(handle_.get(), index, &module));
    return module;
  }
  skinware_patch patch(std::size_t index) const {
    skinware_patch patch{};
    check(skinware_topology_patch(handle_.get(), index, &patch));
    return patch;
  }
  // The sensor with hardware uid `uid`, if the layer has it.
  std::optional<std::size_t> index_of(std::uint32_t uid) const {
    std::size_t index = 0;
    skinware_status status = skinware_topology_index_of(handle_.get(), uid, &index);
    if (status == SKINWARE_E_NOT_FOUND) return std::nullopt;
    check(status);
    return index;
  }
  std::vector<std::uint32_t> uids() const {
    std::vector<std::uint32_t> uids(sensors());
    check(skinware_topology_uids(handle_.get(), uids.data(), uids.size()));
    return uids;
  }
  skinware_topology* get() const noexcept { return handle_.get(); }

 private:
  owned<skinware_topology, skinware_topology_free> handle_;
};

// Builds a topology module by module (a driver's).
class topology_builder {
 public:
  topology_builder(const std::string& name, const std::string& sensor_type, double rate_hz) {
    require_abi();
    skinware_topology_builder* handle = nullptr;
    check(skinware_topology_builder_new(name.c_str(), sensor_type.c_str(), rate_hz, &handle));
    handle_ = owned_t(handle);
  }
  topology_builder& add_module(std::uint32_t patch_id, std::uint32_t module_id,
                               const std::vector<std::uint32_t>& uids) {
    check(skinware_topology_builder_add_module(handle_.get(), patch_id, module_id, uids.data(),
                                               uids.size()));
    return *this;
  }
  topology build() const {
    skinware_topology* handle = nullptr;
    check(skinware_topology_builder_build(handle_.get(), &handle));
    return topology(handle);
  }

 private:
  using owned_t = owned<skinware_topology_builder, skinware_topology_builder_free>;
  owned_t handle_;
};

// One read: the values (a view of the caller's buffer) and what the read said.
template <class T>
struct frame {
  span<const T> values;
  skinware_frame_info info{};
  skinware_tick tick{};
};

class reader;

// The range of reader::periodic(): one frame per tick, fresh or not.
template <class T>
class periodic_frames;
// The range of reader::frames(): every new frame, as soon as it is published.
template <class T>
class new_frames;

// A reader of one channel: a layer (uint16_t per sensor) or a service
// (records). Its reads copy into the caller's buffer.
class reader {
 public:
  reader(const std::string& skin, const std::string& channel,
         const skinware_reader_options& options = skinware_reader_options{}) {
    require_abi();
    skinware_reader* handle = nullptr;
    check(skinware_reader_open(skin.c_str(), channel.c_str(), &options, &handle));
    handle_ = owned_t(handle);
    frame_bytes_ = payload_bytes();
  }
  explicit reader(skinware_reader* adopted) : handle_(adopted) { frame_bytes_ = payload_bytes(); }
  // A contact service's reader: records are skinware_region_contacts.
  static reader contacts(const std::string& skin, const std::string& name = "contact") {
    require_abi();
    skinware_reader* handle = nullptr;
    check(skinware_contacts_open(skin.c_str(), name.c_str(), nullptr, &handle));
    return reader(handle);
  }
  // A motion service's reader: records are skinware_motion_record.
  static reader motion(const std::string& skin, const std::string& name = "motion") {
    require_abi();
    skinware_reader* handle = nullptr;
    check(skinware_motion_open(skin.c_str(), name.c_str(), nullptr, &handle));
    return reader(handle);
  }

  skinware_channel_description describe() const {
    skinware_channel_description description{};
    check(skinware_reader_describe(handle_.get(), &description));
    return description;
  }
  std::size_t payload_bytes() const {
    std::size_t bytes = 0;
    check(skinware_reader_payload_bytes(handle_.get(), &bytes));
    return bytes;
  }
  // A buffer of the right size for this channel's frames, of T values.
  template <class T>
  std::vector<T> buffer() const {
    return std::vector<T>((payload_bytes() + sizeof(T) - 1) / sizeof(T));
  }
  // A layer's topology.
  topology layer_topology() const {
    skinware_topology* handle = nullptr;
    check(skinware_reader_topology(handle_.get(), &handle));
    return topology(handle);
  }
  // A service's label `index` (a region's name).
  std::string label(std::size_t index) const {
    const char* label = nullptr;
    check(skinware_reader_label(handle_.get(), index, &label));
    return label;
  }

  // The newest frame, now (lock-free, never blocks).
  template <class T>
  frame<T> latest(std::vector<T>& out) {
    frame<T> read;
    check(skinware_reader_latest(handle_.get(), out.data(), out.size() * sizeof(T), &read.info));
    read.values = span<const T>(out.data(), values_in<T>(out.size()));
    return read;
  }
  // The next new frame, waiting at most `timeout` (throws timeout_error, writer_gone).
  template <class T>
  frame<T> wait_newer(std::vector<T>& out, std::chrono::nanoseconds timeout) {
    frame<T> read;
    check(skinware_reader_wait_newer(handle_.get(), to_ns(timeout), out.data(), out.size() * sizeof(T),
                                     &read.info));
    read.values = span<const T>(out.data(), values_in<T>(out.size()));
    return read;
  }
  // Asks the writer for a fresh frame and waits for it.
  template <class T>
  frame<T> request(std::vector<T>& out, std::chrono::nanoseconds timeout) {
    frame<T> read;
    check(skinware_reader_request(handle_.get(), to_ns(timeout), out.data(), out.size() * sizeof(T),
                                  &read.info));
    read.values = span<const T>(out.data(), values_in<T>(out.size()));
    return read;
  }
  // Sleeps until `clock`'s next deadline, then reads the newest frame.
  template <class T>
  frame<T> next_periodic(ticker& clock, std::vector<T>& out) {
    frame<T> read;
    check(skinware_reader_next_periodic(handle_.get(), clock.get(), out.data(), out.size() * sizeof(T),
                                        &read.info, &read.tick));
    read.values = span<const T>(out.data(), values_in<T>(out.size()));
    return read;
  }
  // Every `period`, the newest frame: `for (auto& read : r.periodic<uint16_t>(1ms))`.
  // The range ends when the reader (or the range) is stopped. The range refers
  // to this reader: the reader must outlive it and stay where it is meanwhile.
  template <class T>
  periodic_frames<T> periodic(std::chrono::nanoseconds period);
  // Every new frame as soon as it is published; throws writer_gone after
  // `gone_timeout` without a writer. The range ends when the reader is stopped.
  // As with periodic(), the reader must outlive the range and stay put.
  template <class T>
  new_frames<T> frames(std::chrono::nanoseconds gone_timeout = std::chrono::seconds(2));

  skinware_reader_stats stats() const {
    skinware_reader_stats stats{};
    check(skinware_reader_get_stats(handle_.get(), &stats));
    return stats;
  }
  skinware_writer_stats writer_stats() const {
    skinware_writer_stats stats{};
    check(skinware_reader_get_writer_stats(handle_.get(), &stats));
    return stats;
  }
  // Wakes a read blocked in another thread (it throws `stopped`; ranges end).
  void stop() { check(skinware_reader_stop(handle_.get())); }
  skinware_reader* get() const noexcept { return handle_.get(); }

 private:
  // The frame's values within a buffer of `size` T: no stale tail of a larger buffer.
  template <class T>
  std::size_t values_in(std::size_t size) const noexcept {
    return std::min(size, frame_bytes_ / sizeof(T));
  }
  using owned_t = owned<skinware_reader, skinware_reader_close>;
  owned_t handle_;
  std::size_t frame_bytes_ = 0;
};

// An input iterator over a frame source: `Source::advance()` returns false at the end.
template <class Source, class T>
class frame_iterator {
 public:
  using iterator_category = std::input_iterator_tag;
  using value_type = frame<T>;
  using difference_type = std::ptrdiff_t;
  using pointer = const frame<T>*;
  using reference = const frame<T>&;
  frame_iterator() = default;
  explicit frame_iterator(Source* source) : source_(source) { step(); }
  reference operator*() const { return source_->current(); }
  pointer operator->() const { return &source_->current(); }
  frame_iterator& operator++() {
    step();
    return *this;
  }
  bool operator==(const frame_iterator& other) const { return source_ == other.source_; }
  bool operator!=(const frame_iterator& other) const { return source_ != other.source_; }

 private:
  void step() {
    if (source_ != nullptr && !source_->advance()) source_ = nullptr;
  }
  Source* source_ = nullptr;
};

template <class T>
class periodic_frames {
 public:
  periodic_frames(reader& source, std::chrono::nanoseconds period)
      : reader_(&source), clock_(period), buffer_(source.buffer<T>()) {}
  frame_iterator<periodic_frames, T> begin() { return frame_iterator<periodic_frames, T>(this); }
  frame_iterator<periodic_frames, T> end() { return {}; }
  // Stops the ticks (from another thread too): the range ends at once.
  void stop() { clock_.stop(); }

  const frame<T>& current() const { return current_; }
  bool advance() {
    for (;;) {
      skinware_status status = skinware_reader_next_periodic(
          reader_->get(), clock_.get(), buffer_.data(), buffer_.size() * sizeof(T), &current_.info,
          &current_.tick);
      if (status == SKINWARE_OK) {
        current_.values = span<const T>(buffer_.data(), buffer_.size());
        return true;
      }
      if (status == SKINWARE_E_STOPPED) return false;
      if (status == SKINWARE_E_NO_FRAME_YET) continue;  // nothing published yet: next tick
      throw_status(status);
    }
  }

 private:
  reader* reader_;
  ticker clock_;
  std::vector<T> buffer_;
  frame<T> current_;
};

template <class T>
class new_frames {
 public:
  new_frames(reader& source, std::chrono::nanoseconds gone_timeout)
      : reader_(&source), gone_timeout_(gone_timeout), buffer_(source.buffer<T>()) {}
  frame_iterator<new_frames, T> begin() { return frame_iterator<new_frames, T>(this); }
  frame_iterator<new_frames, T> end() { return {}; }

  const frame<T>& current() const { return current_; }
  bool advance() {
    // Short waits, so that a writer gone for `gone_timeout` is noticed.
    const std::uint64_t slice_ns = 250000000;
    bool gone = false;
    std::chrono::steady_clock::time_point gone_since{};
    for (;;) {
      skinware_status status = skinware_reader_wait_newer(
          reader_->get(), slice_ns, buffer_.data(), buffer_.size() * sizeof(T), &current_.info);
      if (status == SKINWARE_OK) {
        current_.values = span<const T>(buffer_.data(), buffer_.size());
        return true;
      }
      if (status == SKINWARE_E_STOPPED) return false;
      if (status == SKINWARE_E_TIMEOUT) {
        gone = false;
        continue;
      }
      if (status == SKINWARE_E_WRITER_GONE) {
        auto now = std::chrono::steady_clock::now();
        if (!gone) gone_since = now;
        gone = true;
        if (now - gone_since < gone_timeout_) continue;
      }
      throw_status(status);
    }
  }

 private:
  reader* reader_;
  std::chrono::nanoseconds gone_timeout_;
  std::vector<T> buffer_;
  frame<T> current_;
};

template <class T>
periodic_frames<T> reader::periodic(std::chrono::nanoseconds period) {
  return periodic_frames<T>(*this, period);
}

template <class T>
new_frames<T> reader::frames(std::chrono::nanoseconds gone_timeout) {
  return new_frames<T>(*this, gone_timeout);
}

// The writer of one layer: a driver.
class writer {
 public:
  writer(const std::string& skin, const std::string& layer, const topology& layout,
         const skinware_writer_options& options = skinware_writer_options{}) {
    require_abi();
    skinware_writer* handle = nullptr;
    check(skinware_writer_create(skin.c_str(), layer.c_str(), layout.get(), &options, &handle));
    handle_ = owned_t(handle);
  }
  // Publishes one frame (one response per sensor); returns its sequence number.
  std::uint64_t publish(span<const std::uint16_t> responses, std::uint64_t status = 0,
                        std::uint64_t acquired_ns = 0) {
    std::uint64_t seq = 0;
    check(skinware_writer_publish(handle_.get(), responses.data(), responses.size(), status,
                                  acquired_ns, &seq));
    return seq;
  }
  void set_state(skinware_writer_state state) {
    check(skinware_writer_set_state(handle_.get(), static_cast<int32_t>(state)));
  }
  skinware_writer_state state() const {
    skinware_writer_state state{};
    check(skinware_writer_get_state(handle_.get(), &state));
    return state;
  }
  // A sporadic writer: true if a reader asked for a frame within `timeout`.
  bool wait_request(std::chrono::nanoseconds timeout) {
    bool requested = false;
    check(skinware_writer_wait_request(handle_.get(), to_ns(timeout), &requested));
    return requested;
  }
  // A periodic writer's schedule, at the layer's rate.
  ticker schedule() const {
    skinware_ticker* handle = nullptr;
    check(skinware_writer_ticker(handle_.get(), &handle));
    return ticker(handle);
  }
  skinware_writer_stats stats() const {
    skinware_writer_stats stats{};
    check(skinware_writer_get_stats(handle_.get(), &stats));
    return stats;
  }
  // Wakes wait_request() blocked in another thread (it throws `stopped`).
  void stop() { check(skinware_writer_stop(handle_.get())); }

 private:
  using owned_t = owned<skinware_writer, skinware_writer_close>;
  owned_t handle_;
};

// The skin's geometry. Its spans stay valid while it lives.
class geometry {
 public:
  explicit geometry(const std::string& skin) {
    require_abi();
    skinware_geometry* handle = nullptr;
    check(skinware_geometry_open(skin.c_str(), &handle));
    handle_ = owned_t(handle);
    check(skinware_geometry_describe(handle_.get(), &summary_));
    check(skinware_geometry_get_arrays(handle_.get(), &arrays_));
  }
  // Moved: the moved-from geometry is empty (its spans are empty, not dangling).
  geometry(geometry&& other) noexcept
      : handle_(std::move(other.handle_)), summary_(other.summary_), arrays_(other.arrays_) {
    other.summary_ = skinware_geometry_summary{};
    other.arrays_ = skinware_geometry_arrays{};
  }
  geometry& operator=(geometry&& other) noexcept {
    if (this != &other) {
      handle_ = std::move(other.handle_);
      summary_ = std::exchange(other.summary_, skinware_geometry_summary{});
      arrays_ = std::exchange(other.arrays_, skinware_geometry_arrays{});
    }
    return *this;
  }
  const skinware_geometry_summary& summary() const noexcept { return summary_; }
  std::size_t sensors() const noexcept { return summary_.sensors; }
  // x, y, z per sensor, metres.
  span<const float> positions() const { return {arrays_.positions, 3 * arrays_.sensors}; }
  span<const float> normals() const { return {arrays_.normals, 3 * arrays_.sensors}; }
  span<const float> radii() const { return {arrays_.radii, arrays_.sensors}; }
  // x, y per sensor on the 2-D map, metres.
  span<const float> map() const { return {arrays_.map, 2 * arrays_.sensors}; }
  // The neighbours (global indices) of sensor `index`.
  span<const std::uint32_t> neighbours(std::size_t index) const {
    if (index >= arrays_.sensors) {
      throw not_found(SKINWARE_E_NOT_FOUND, "sensor " + std::to_string(index) + ": the skin has " +
                                                std::to_string(arrays_.sensors));
    }
    std::uint32_t first = arrays_.neighbour_offsets[index];
    std::uint32_t last = arrays_.neighbour_offsets[index + 1];
    return {arrays_.neighbours + first, static_cast<std::size_t>(last - first)};
  }
  skinware_geometry_layer layer(std::size_t index) const {
    skinware_geometry_layer layer{};
    check(skinware_geometry_get_layer(handle_.get(), index, &layer));
    return layer;
  }
  std::string link(std::size_t index) const {
    const char* name = nullptr;
    check(skinware_geometry_link(handle_.get(), index, &name));
    return name;
  }
  skinware_region region(std::size_t index) const {
    skinware_region region{};
    check(skinware_geometry_region(handle_.get(), index, &region));
    return region;
  }
  // The sensors of region `name`.
  span<const std::uint32_t> region(const std::string& name) const {
    std::size_t index = 0;
    check(skinware_geometry_region_index(handle_.get(), name.c_str(), &index));
    skinware_region found = region(index);
    return {found.sensors, found.sensor_count};
  }
  skinware_sensor_ref locate(std::size_t index) const {
    skinware_sensor_ref found{};
    check(skinware_geometry_locate(handle_.get(), index, &found));
    return found;
  }

 private:
  using owned_t = owned<skinware_geometry, skinware_geometry_free>;
  owned_t handle_;
  skinware_geometry_summary summary_{};
  skinware_geometry_arrays arrays_{};
};

// One channel, as `skin ls` lists it.
struct channel {
  std::string skin;
  std::string name;
  skinware_channel_kind kind;
  skinware_writer_state state;
  std::size_t sensors;
  std::uint64_t payload_bytes;
  std::uint64_t frames;
  std::uint32_t writer_pid;
  std::string problem;  // empty if the channel can be read
};

// The channels of `skin` (every skin if empty), sorted by skin and name.
inline std::vector<channel> list_channels(const std::string& skin = "") {
  require_abi();
  skinware_channel_list* list = nullptr;
  check(skinware_list_channels(skin.empty() ? nullptr : skin.c_str(), &list));
  owned<skinware_channel_list, skinware_channel_list_free> owner(list);
  std::size_t count = 0;
  check(skinware_channel_list_len(list, &count));
  std::vector<channel> channels;
  channels.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    skinware_channel_info info{};
    check(skinware_channel_list_get(list, i, &info));
    channels.push_back(channel{info.skin, info.name, info.kind, info.state, info.sensors,
                               info.payload_bytes, info.frames, info.writer_pid,
                               info.problem != nullptr ? info.problem : ""});
  }
  return channels;
}

}  // namespace skinware

#endif  // SKINWARE_HPP
