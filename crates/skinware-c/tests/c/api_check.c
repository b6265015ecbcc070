/*
 * The C API's test program, driven by crates/skin/tests/integration/c_api.rs
 * against `skin run`'s virtual skin. Each mode prints what the Rust side
 * checks, and exits non-zero (saying why) on a failed expectation.
 *
 *   api_check frames SKIN LAYER N     N new frames: "seq SEQ CHECKSUM" lines
 *   api_check modes SKIN LAYER        every read mode, topology, geometry, services, listing
 *   api_check errors SKIN LAYER       bad arguments give the right codes and messages
 *   api_check spin SKIN LAYER         latest() in a tight loop, forever (to be SIGKILLed)
 *   api_check write SKIN LAYER N HZ   a C writer: N frames of pattern(seq) at HZ
 *   api_check serve SKIN LAYER N      a sporadic C writer answering N requests
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <skinware.h>

static int failures = 0;

#define EXPECT(condition, ...)                                         \
  do {                                                                 \
    if (!(condition)) {                                                \
      fprintf(stderr, "FAILED %s:%d: %s: ", __FILE__, __LINE__, #condition); \
      fprintf(stderr, __VA_ARGS__);                                    \
      fprintf(stderr, " (last error: %s)\n", skinware_last_error());   \
      failures++;                                                      \
    }                                                                  \
  } while (0)

#define OK(call) EXPECT((call) == SKINWARE_OK, "%s", #call)

/* FNV-1a over the responses' bytes: what the Rust side computes too. */
static uint64_t checksum(const uint16_t *values, size_t count) {
  uint64_t hash = 0xcbf29ce484222325ull;
  for (size_t i = 0; i < count; ++i) {
    uint8_t bytes[2] = {(uint8_t)(values[i] & 0xFF), (uint8_t)(values[i] >> 8)};
    for (int b = 0; b < 2; ++b) hash = (hash ^ bytes[b]) * 0x100000001b3ull;
  }
  return hash;
}

/* The value a C writer publishes for sensor i of frame seq. */
static uint16_t pattern(uint64_t seq, size_t i) { return (uint16_t)((seq * 31 + i * 7) & 0xFFFF); }

static skinware_reader *open_layer(const char *skin, const char *layer, size_t *sensors) {
  skinware_reader *reader = NULL;
  skinware_status status = skinware_reader_open(skin, layer, NULL, &reader);
  if (status != SKINWARE_OK) {
    fprintf(stderr, "cannot open %s/%s: %s: %s\n", skin, layer, skinware_status_name(status), skinware_last_error());
    exit(1);
  }
  size_t bytes = 0;
  OK(skinware_reader_payload_bytes(reader, &bytes));
  *sensors = bytes / 2;
  return reader;
}

static int frames(const char *skin, const char *layer, long n) {
  size_t sensors;
  skinware_reader *reader = open_layer(skin, layer, &sensors);
  uint16_t *buffer = malloc(sensors * sizeof *buffer);
  for (long i = 0; i < n; ++i) {
    skinware_frame_info info;
    skinware_status status = skinware_reader_wait_newer(reader, 2000000000ull, buffer, sensors * 2, &info);
    EXPECT(status == SKINWARE_OK, "wait_newer: %s", skinware_status_name(status));
    if (status != SKINWARE_OK) break;
    printf("seq %" PRIu64 " %" PRIu64 "\n", info.seq, checksum(buffer, sensors));
  }
  fflush(stdout);
  free(buffer);
  OK(skinware_reader_close(reader));
  return failures != 0;
}

static void check_topology(skinware_reader *reader, size_t sensors) {
  skinware_topology *topology = NULL;
  OK(skinware_reader_topology(reader, &topology));
  skinware_topology_summary summary;
  OK(skinware_topology_describe(topology, &summary));
  EXPECT(summary.sensors == sensors, "topology has %zu sensors, frames %zu", summary.sensors, sensors);
  EXPECT(summary.modules > 0 && summary.patches > 0, "%zu modules, %zu patches", summary.modules, summary.patches);
  uint32_t *uids = malloc(sensors * sizeof *uids);
  OK(skinware_topology_uids(topology, uids, sensors));
  size_t index = 0, probe = sensors / 2;
  OK(skinware_topology_index_of(topology, uids[probe], &index));
  EXPECT(index == probe, "uid %u found at %zu, not %zu", uids[probe], index, probe);
  skinware_sensor sensor;
  OK(skinware_topology_sensor(topology, probe, &sensor));
  EXPECT(sensor.uid == uids[probe], "sensor %zu uid %u != %u", probe, sensor.uid, uids[probe]);
  skinware_module module;
  OK(skinware_topology_module(topology, sensor.module_index, &module));
  EXPECT(module.id == sensor.module_id && probe >= module.first_sensor && probe < module.first_sensor + module.sensors,
         "sensor %zu not inside its module %u", probe, module.id);
  skinware_patch patch;
  OK(skinware_topology_patch(topology, module.patch_index, &patch));
  EXPECT(patch.id == module.patch_id, "module's patch %u != %u", patch.id, module.patch_id);
  EXPECT(skinware_topology_index_of(topology, 0xFFFFFFFFu, &index) == SKINWARE_E_NOT_FOUND, "a missing uid");
  free(uids);
  OK(skinware_topology_free(topology));
  printf("topology ok: %zu sensors, %zu modules, %zu patches\n", summary.sensors, summary.modules, summary.patches);
}

static void check_geometry(const char *skin) {
  skinware_geometry *geometry = NULL;
  skinware_status status = skinware_geometry_open(skin, &geometry);
  EXPECT(status == SKINWARE_OK, "geometry_open: %s", skinware_status_name(status));
  if (status != SKINWARE_OK) return;
  skinware_geometry_summary summary;
  skinware_geometry_arrays arrays;
  OK(skinware_geometry_describe(geometry, &summary));
  OK(skinware_geometry_get_arrays(geometry, &arrays));
  EXPECT(arrays.sensors == summary.sensors && summary.sensors > 0, "arrays of %zu sensors", arrays.sensors);
  EXPECT(arrays.neighbour_offsets[arrays.sensors] == arrays.neighbour_entries, "neighbour offsets end at %u",
         arrays.neighbour_offsets[arrays.sensors]);
  double norm = arrays.normals[0] * arrays.normals[0] + arrays.normals[1] * arrays.normals[1] +
                arrays.normals[2] * arrays.normals[2];
  EXPECT(norm > 0.98 && norm < 1.02, "normal 0 has squared norm %f", norm);
  for (size_t r = 0; r < summary.regions; ++r) {
    skinware_region region;
    OK(skinware_geometry_region(geometry, r, &region));
    size_t found = 99;
    OK(skinware_geometry_region_index(geometry, region.name, &found));
    EXPECT(found == r, "region %s at %zu", region.name, found);
    for (size_t i = 0; i < region.sensor_count; ++i) EXPECT(region.sensors[i] < summary.sensors, "region sensor");
  }
  size_t layers_total = 0;
  for (size_t l = 0; l < summary.layers; ++l) {
    skinware_geometry_layer layer;
    OK(skinware_geometry_get_layer(geometry, l, &layer));
    EXPECT(layer.first_sensor == layers_total, "layer %s starts at %zu", layer.name, layer.first_sensor);
    layers_total += layer.sensors;
  }
  EXPECT(layers_total == summary.sensors, "layers hold %zu of %zu sensors", layers_total, summary.sensors);
  skinware_sensor_ref where;
  OK(skinware_geometry_locate(geometry, summary.sensors - 1, &where));
  EXPECT(where.layer == summary.layers - 1, "the last sensor is in layer %zu", where.layer);
  EXPECT(skinware_geometry_locate(geometry, summary.sensors, &where) == SKINWARE_E_NOT_FOUND, "past the end");
  printf("geometry ok: %zu sensors, %zu layers, %zu regions, %zu neighbour entries\n", summary.sensors,
         summary.layers, summary.regions, summary.neighbour_entries);
  OK(skinware_geometry_free(geometry));
}

static void check_services(const char *skin) {
  skinware_reader *contacts = NULL, *motion = NULL;
  OK(skinware_contacts_open(skin, "contact", NULL, &contacts));
  OK(skinware_motion_open(skin, "motion", NULL, &motion));
  if (contacts == NULL || motion == NULL) return;
  skinware_channel_description description;
  OK(skinware_reader_describe(contacts, &description));
  EXPECT(description.kind == SKINWARE_KIND_SERVICE && description.value_bytes == sizeof(skinware_region_contacts),
         "contact records of %zu bytes", description.value_bytes);
  EXPECT(strcmp(description.schema_name, "skinware.contacts") == 0, "schema %s", description.schema_name);
  skinware_region_contacts *records = calloc(description.values, sizeof *records);
  skinware_frame_info info;
  OK(skinware_reader_wait_newer(contacts, 3000000000ull, records, description.values * sizeof *records, &info));
  const char *label = NULL;
  OK(skinware_reader_label(contacts, 0, &label));
  EXPECT(label != NULL && label[0] != '\0', "a region label");
  EXPECT(records[0].count <= SKINWARE_MAX_CONTACTS, "%u contacts", records[0].count);
  skinware_motion_record *moves = calloc(description.values, sizeof *moves);
  OK(skinware_reader_describe(motion, &description));
  OK(skinware_reader_wait_newer(motion, 3000000000ull, moves, description.values * sizeof *moves, &info));
  printf("services ok: contact and motion, %zu regions, first %s\n", description.values, label ? label : "?");
  free(records);
  free(moves);
  OK(skinware_reader_close(contacts));
  OK(skinware_reader_close(motion));
}

static int modes(const char *skin, const char *layer) {
  EXPECT(skinware_abi_compatible(), "ABI %u vs header %u", skinware_abi_version(), SKINWARE_ABI_VERSION);
  size_t sensors;
  skinware_reader *reader = open_layer(skin, layer, &sensors);
  uint16_t *buffer = malloc(sensors * sizeof *buffer);
  skinware_frame_info info, again;
  OK(skinware_reader_wait_newer(reader, 3000000000ull, buffer, sensors * 2, &info));
  OK(skinware_reader_latest(reader, buffer, sensors * 2, &again));
  EXPECT(again.seq >= info.seq, "latest went back from %" PRIu64 " to %" PRIu64, info.seq, again.seq);
  OK(skinware_reader_request(reader, 3000000000ull, buffer, sensors * 2, &info));
  EXPECT(info.seq > again.seq && info.fresh, "a request answered by %" PRIu64 " after %" PRIu64, info.seq, again.seq);
  skinware_ticker *ticker = NULL;
  OK(skinware_ticker_new(5000000ull, &ticker));
  uint64_t previous = 0;
  for (int i = 0; i < 20; ++i) {
    skinware_tick tick;
    OK(skinware_reader_next_periodic(reader, ticker, buffer, sensors * 2, &info, &tick));
    EXPECT(tick.deadline_ns > previous, "deadlines go forward");
    previous = tick.deadline_ns;
  }
  OK(skinware_ticker_free(ticker));
  skinware_channel_description description;
  OK(skinware_reader_describe(reader, &description));
  EXPECT(description.kind == SKINWARE_KIND_LAYER && description.values == sensors, "a layer of %zu", description.values);
  EXPECT(description.state == SKINWARE_STATE_RUNNING, "state %d", (int)description.state);
  EXPECT(description.period_ns > 0, "a periodic writer");
  skinware_reader_stats stats;
  OK(skinware_reader_get_stats(reader, &stats));
  EXPECT(stats.reads >= 23, "%" PRIu64 " reads", stats.reads);
  skinware_writer_stats writer_stats;
  OK(skinware_reader_get_writer_stats(reader, &writer_stats));
  EXPECT(writer_stats.frames >= info.seq, "writer frames");
  printf("modes ok: latest, wait_newer, request, periodic; %" PRIu64 " reads\n", stats.reads);
  /* Anticipation: a reader that spins just before each frame. */
  skinware_reader_options options = {.allow_gone = 0, .anticipate_ns = 200000};
  skinware_reader *anticipating = NULL;
  OK(skinware_reader_open(skin, layer, &options, &anticipating));
  for (int i = 0; i < 5; ++i) OK(skinware_reader_wait_newer(anticipating, 2000000000ull, buffer, sensors * 2, &info));
  OK(skinware_reader_close(anticipating));
  check_topology(reader, sensors);
  check_geometry(skin);
  check_services(skin);
  skinware_channel_list *list = NULL;
  OK(skinware_list_channels(skin, &list));
  size_t count = 0, found = 0;
  OK(skinware_channel_list_len(list, &count));
  for (size_t i = 0; i < count; ++i) {
    skinware_channel_info channel;
    OK(skinware_channel_list_get(list, i, &channel));
    if (strcmp(channel.name, layer) == 0 && channel.kind == SKINWARE_KIND_LAYER && channel.sensors == sensors) found++;
  }
  EXPECT(found == 1, "the listing has %s once (%zu)", layer, found);
  OK(skinware_channel_list_free(list));
  printf("listing ok: %zu channels\n", count);
  free(buffer);
  OK(skinware_reader_close(reader));
  return failures != 0;
}

#define EXPECT_CODE(call, code)                                                                     \
  do {                                                                                              \
    skinware_status got_ = (call);                                                                  \
    EXPECT(got_ == (code), "%s gave %s, not %s", #call, skinware_status_name(got_), #code);         \
    EXPECT(got_ == SKINWARE_OK || strlen(skinware_last_error()) > 10, "%s left no message", #call); \
  } while (0)

static int errors(const char *skin, const char *layer) {
  size_t sensors;
  skinware_reader *reader = open_layer(skin, layer, &sensors);
  uint16_t *buffer = malloc(sensors * sizeof *buffer);
  skinware_reader *other = NULL;
  /* NULL pointers. */
  EXPECT_CODE(skinware_reader_open(NULL, layer, NULL, &other), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT(strstr(skinware_last_error(), "skin is NULL") != NULL, "the message names the argument: %s", skinware_last_error());
  EXPECT_CODE(skinware_reader_open(skin, layer, NULL, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_latest(NULL, buffer, sensors * 2, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_latest(reader, NULL, sensors * 2, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_describe(reader, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_topology_describe(NULL, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_writer_publish(NULL, buffer, sensors, 0, 0, NULL), SKINWARE_E_INVALID_ARGUMENT);
  /* Wrong sizes. */
  EXPECT_CODE(skinware_reader_latest(reader, buffer, sensors * 2 - 1, NULL), SKINWARE_E_BUFFER_TOO_SMALL);
  EXPECT(strstr(skinware_last_error(), "bytes") != NULL, "says how many bytes: %s", skinware_last_error());
  EXPECT_CODE(skinware_reader_wait_newer(reader, 1000000, buffer, 0, NULL), SKINWARE_E_BUFFER_TOO_SMALL);
  /* A missing skin, a missing channel, the wrong kind of channel. */
  EXPECT_CODE(skinware_reader_open("no_such_skin", layer, NULL, &other), SKINWARE_E_NOT_FOUND);
  EXPECT(strstr(skinware_last_error(), "skin ls") != NULL, "says how to look: %s", skinware_last_error());
  EXPECT_CODE(skinware_reader_open(skin, "no_such_layer", NULL, &other), SKINWARE_E_NOT_FOUND);
  EXPECT_CODE(skinware_contacts_open(skin, layer, NULL, &other), SKINWARE_E_SCHEMA_MISMATCH);
  EXPECT_CODE(skinware_reader_open(skin, "bad/name", NULL, &other), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_open(skin, "\xff\xfe", NULL, &other), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT(other == NULL, "no handle written on failure");
  /* Out of range. */
  EXPECT_CODE(skinware_ticker_new(0, (skinware_ticker **)&other), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_label(reader, 0, (const char **)&other), SKINWARE_E_INVALID_ARGUMENT);
  skinware_topology *topology = NULL;
  OK(skinware_reader_topology(reader, &topology));
  skinware_sensor sensor;
  EXPECT_CODE(skinware_topology_sensor(topology, sensors, &sensor), SKINWARE_E_NOT_FOUND);
  EXPECT_CODE(skinware_topology_uids(topology, (uint32_t *)buffer, 1), SKINWARE_E_BUFFER_TOO_SMALL);
  skinware_writer *writer = NULL;
  skinware_writer_options bad_options = {.slots = 1, .access = 0};
  EXPECT_CODE(skinware_writer_create(skin, "c_bad", topology, &bad_options, &writer), SKINWARE_E_INVALID_ARGUMENT);
  bad_options.slots = 0;
  bad_options.access = 9;
  EXPECT_CODE(skinware_writer_create(skin, "c_bad", topology, &bad_options, &writer), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_writer_create(skin, layer, topology, NULL, &writer), SKINWARE_E_BUSY);
  /* Closed handles, double closes, made-up handles, handles of another type. */
  OK(skinware_topology_free(topology));
  EXPECT_CODE(skinware_topology_free(topology), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_topology_sensor(topology, 0, &sensor), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT(strstr(skinware_last_error(), "closed") != NULL, "says closed: %s", skinware_last_error());
  EXPECT_CODE(skinware_reader_latest((skinware_reader *)(uintptr_t)0xdeadbeef, buffer, sensors * 2, NULL),
              SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_topology_free((skinware_topology *)reader), SKINWARE_E_INVALID_ARGUMENT);
  OK(skinware_reader_latest(reader, buffer, sensors * 2, NULL));
  OK(skinware_reader_close(reader));
  EXPECT_CODE(skinware_reader_latest(reader, buffer, sensors * 2, NULL), SKINWARE_E_INVALID_ARGUMENT);
  EXPECT_CODE(skinware_reader_close(reader), SKINWARE_E_INVALID_ARGUMENT);
  OK(skinware_reader_close(NULL));
  /* Stopped readers return at once. */
  reader = open_layer(skin, layer, &sensors);
  OK(skinware_reader_stop(reader));
  EXPECT_CODE(skinware_reader_wait_newer(reader, 5000000000ull, buffer, sensors * 2, NULL), SKINWARE_E_STOPPED);
  OK(skinware_reader_close(reader));
  EXPECT(strcmp(skinware_status_name(SKINWARE_E_TIMEOUT), "SKINWARE_E_TIMEOUT") == 0, "status names");
  free(buffer);
  printf("errors ok\n");
  return failures != 0;
}

static int spin(const char *skin, const char *layer) {
  size_t sensors;
  skinware_reader *reader = open_layer(skin, layer, &sensors);
  uint16_t *buffer = malloc(sensors * sizeof *buffer);
  printf("spinning\n");
  fflush(stdout);
  for (;;) skinware_reader_latest(reader, buffer, sensors * 2, NULL);
  return 0; /* never: the test SIGKILLs it */
}

static int write_frames(const char *skin, const char *layer, long n, double hz) {
  skinware_topology *topology = NULL;
  OK(skinware_topology_uniform(layer, "pressure", hz, 2, 3, 12, &topology));
  skinware_writer *writer = NULL;
  skinware_status status = skinware_writer_create(skin, layer, topology, NULL, &writer);
  if (status != SKINWARE_OK) {
    fprintf(stderr, "writer_create: %s: %s\n", skinware_status_name(status), skinware_last_error());
    return 1;
  }
  OK(skinware_topology_free(topology));
  skinware_ticker *ticker = NULL;
  OK(skinware_writer_ticker(writer, &ticker));
  uint16_t responses[72];
  printf("writing\n");
  fflush(stdout);
  for (uint64_t seq = 1; seq <= (uint64_t)n; ++seq) {
    OK(skinware_ticker_wait(ticker, NULL));
    for (size_t i = 0; i < 72; ++i) responses[i] = pattern(seq, i);
    uint64_t published = 0;
    OK(skinware_writer_publish(writer, responses, 72, 0, 0, &published));
    EXPECT(published == seq, "published %" PRIu64 " as %" PRIu64, seq, published);
  }
  EXPECT(skinware_writer_publish(writer, responses, 71, 0, 0, NULL) == SKINWARE_E_INVALID_ARGUMENT, "71 of 72");
  EXPECT(skinware_writer_set_state(writer, 3) == SKINWARE_E_INVALID_ARGUMENT, "gone is not settable");
  OK(skinware_writer_set_state(writer, SKINWARE_STATE_PAUSED));
  skinware_writer_state state;
  OK(skinware_writer_get_state(writer, &state));
  EXPECT(state == SKINWARE_STATE_PAUSED, "state %d", (int)state);
  OK(skinware_ticker_free(ticker));
  OK(skinware_writer_close(writer));
  printf("written %ld\n", n);
  return failures != 0;
}

static int serve(const char *skin, const char *layer, long n) {
  skinware_topology_builder *builder = NULL;
  OK(skinware_topology_builder_new(layer, "pressure", 0.0, &builder));
  uint32_t uids[4] = {100, 101, 102, 103};
  OK(skinware_topology_builder_add_module(builder, 1, 10, uids, 2));
  OK(skinware_topology_builder_add_module(builder, 2, 20, uids + 2, 2));
  skinware_topology *topology = NULL;
  OK(skinware_topology_builder_build(builder, &topology));
  OK(skinware_topology_builder_add_module(builder, 3, 30, uids, 1));
  EXPECT(skinware_topology_builder_build(builder, &topology) == SKINWARE_E_INVALID_ARGUMENT, "a duplicate uid");
  OK(skinware_topology_builder_free(builder));
  skinware_writer *writer = NULL;
  OK(skinware_writer_create(skin, layer, topology, NULL, &writer));
  OK(skinware_topology_free(topology));
  skinware_ticker *ticker = NULL;
  EXPECT(skinware_writer_ticker(writer, &ticker) == SKINWARE_E_INVALID_ARGUMENT, "a sporadic writer has no ticker");
  printf("serving\n");
  fflush(stdout);
  long answered = 0;
  uint64_t deadline = skinware_monotonic_ns() + 20000000000ull;
  while (answered < n && skinware_monotonic_ns() < deadline) {
    bool requested = false;
    OK(skinware_writer_wait_request(writer, 100000000ull, &requested));
    if (!requested) continue;
    uint16_t responses[4];
    for (size_t i = 0; i < 4; ++i) responses[i] = pattern((uint64_t)answered + 1, i);
    OK(skinware_writer_publish(writer, responses, 4, 0, 0, NULL));
    answered++;
  }
  OK(skinware_writer_close(writer));
  printf("answered %ld\n", answered);
  return failures != 0 || answered < n;
}

int main(int argc, char **argv) {
  if (argc < 4) {
    fprintf(stderr, "usage: %s frames|modes|errors|spin|write|serve SKIN LAYER [N [HZ]]\n", argv[0]);
    return 2;
  }
  const char *mode = argv[1], *skin = argv[2], *layer = argv[3];
  long n = argc > 4 ? strtol(argv[4], NULL, 10) : 10;
  int result;
  if (strcmp(mode, "frames") == 0) result = frames(skin, layer, n);
  else if (strcmp(mode, "modes") == 0) result = modes(skin, layer);
  else if (strcmp(mode, "errors") == 0) result = errors(skin, layer);
  else if (strcmp(mode, "spin") == 0) result = spin(skin, layer);
  else if (strcmp(mode, "write") == 0) result = write_frames(skin, layer, n, argc > 5 ? atof(argv[5]) : 100.0);
  else if (strcmp(mode, "serve") == 0) result = serve(skin, layer, n);
  else {
    fprintf(stderr, "unknown mode %s\n", mode);
    return 2;
  }
  if (failures) fprintf(stderr, "%d expectations failed\n", failures);
  return result;
}
