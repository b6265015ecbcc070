/*
 * A skin driver written in C: iCub MTB skin boards behind an SLCAN adapter
 * (a serial line), published as one skinware layer.
 *
 * It speaks the real protocols: SLCAN (Lawicel ASCII) to the adapter, and
 * the MTB's CAN messages to the boards (SET_BRD_CFG 0x4D, SET_TXMODE 0x07;
 * a head and a tail frame per 12-taxel triangle, 8-bit inverted values).
 * Without the hardware, `skin emulate` is the device, on a pseudo-terminal:
 *
 *   skin emulate icub-mtb --boards 2 --triangles 4 --link /tmp/mtb &
 *   ./mtb_driver /tmp/mtb cskin mtb 2 4 10   # device, skin, layer, boards, triangles, seconds (0: forever)
 *   skin ls cskin                             # the layer, read like any other
 *
 * Build: cc mtb_driver.c $(pkg-config --cflags --libs skinware) -o mtb_driver
 */
#define _DEFAULT_SOURCE /* cfmakeraw */
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <unistd.h>

#include <skinware.h>

#define TAXELS 12
#define PERIOD_MS 20

static volatile sig_atomic_t stopping = 0;
static void on_signal(int signal) { (void)signal; stopping = 1; }

static int fail(const char *what, skinware_status status) {
  fprintf(stderr, "mtb_driver: %s: %s: %s\n", what, skinware_status_name(status), skinware_last_error());
  return 1;
}

/* Sends one standard CAN frame as an SLCAN line: tIIILDD..\r */
static int send_frame(int fd, unsigned id, const uint8_t *data, unsigned len) {
  char line[32];
  int n = snprintf(line, sizeof line, "t%03X%u", id & 0x7FF, len);
  for (unsigned i = 0; i < len; ++i) n += snprintf(line + n, sizeof line - (size_t)n, "%02X", data[i]);
  line[n++] = '\r';
  return write(fd, line, (size_t)n) == n ? 0 : -1;
}

static int hex(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  return -1;
}

/* Parses a standard data frame line (without its \r); 0 if it is one. */
static int parse_frame(const char *line, size_t length, unsigned *id, uint8_t *data, unsigned *len) {
  if (length < 5 || line[0] != 't') return -1;
  int a = hex(line[1]), b = hex(line[2]), c = hex(line[3]), l = hex(line[4]);
  if (a < 0 || b < 0 || c < 0 || l < 0 || l > 8 || length < 5 + 2 * (size_t)l) return -1;
  *id = (unsigned)(a << 8 | b << 4 | c);
  *len = (unsigned)l;
  for (int i = 0; i < l; ++i) {
    int hi = hex(line[5 + 2 * i]), lo = hex(line[6 + 2 * i]);
    if (hi < 0 || lo < 0) return -1;
    data[i] = (uint8_t)(hi << 4 | lo);
  }
  return 0;
}

static int open_adapter(const char *path) {
  int fd = open(path, O_RDWR | O_NOCTTY);
  if (fd < 0) return -1;
  struct termios tty;
  if (tcgetattr(fd, &tty) == 0) {
    cfmakeraw(&tty);
    tcsetattr(fd, TCSANOW, &tty);
  }
  /* Close (in case), 1 Mbit/s, open. */
  const char *setup = "C\rS8\rO\r";
  if (write(fd, setup, strlen(setup)) != (ssize_t)strlen(setup)) {
    close(fd);
    return -1;
  }
  return fd;
}

int main(int argc, char **argv) {
  if (argc < 6) {
    fprintf(stderr, "usage: %s DEVICE SKIN LAYER BOARDS TRIANGLES [SECONDS]\n", argv[0]);
    return 2;
  }
  const char *device = argv[1], *skin = argv[2], *layer = argv[3];
  int boards = atoi(argv[4]), triangles = atoi(argv[5]);
  double seconds = argc > 6 ? atof(argv[6]) : 0.0;
  if (boards < 1 || boards > 15 || triangles < 1 || triangles > 16) {
    fprintf(stderr, "mtb_driver: BOARDS must be 1 to 15 and TRIANGLES 1 to 16\n");
    return 2;
  }
  signal(SIGINT, on_signal);
  signal(SIGTERM, on_signal);

  /* The topology: a patch per board, a module per triangle, uid b<<8 | t<<4 | k. */
  skinware_topology_builder *builder = NULL;
  skinware_status status = skinware_topology_builder_new(layer, "pressure", 1000.0 / PERIOD_MS, &builder);
  if (status != SKINWARE_OK) return fail("starting the topology", status);
  for (int b = 1; b <= boards; ++b) {
    for (int t = 0; t < triangles; ++t) {
      uint32_t uids[TAXELS];
      for (int k = 0; k < TAXELS; ++k) uids[k] = (uint32_t)(b << 8 | t << 4 | k);
      status = skinware_topology_builder_add_module(builder, (uint32_t)b, (uint32_t)(b * 16 + t), uids, TAXELS);
      if (status != SKINWARE_OK) return fail("adding a triangle", status);
    }
  }
  skinware_topology *topology = NULL;
  status = skinware_topology_builder_build(builder, &topology);
  skinware_topology_builder_free(builder);
  if (status != SKINWARE_OK) return fail("building the topology", status);

  int fd = open_adapter(device);
  if (fd < 0) {
    fprintf(stderr, "mtb_driver: cannot open the SLCAN adapter %s: %s (is `skin emulate icub-mtb --link %s` running?)\n",
            device, strerror(errno), device);
    return 1;
  }
  /* Every board: 20 ms period, no-load 0xF0, then start streaming (0x07 0 is start). */
  for (int b = 1; b <= boards; ++b) {
    const uint8_t config[4] = {0x4D, 0x00, PERIOD_MS, 0xF0};
    const uint8_t start[2] = {0x07, 0x00};
    if (send_frame(fd, 0x200u | (unsigned)b, config, 4) || send_frame(fd, 0x200u | (unsigned)b, start, 2)) {
      fprintf(stderr, "mtb_driver: writing to %s: %s\n", device, strerror(errno));
      return 1;
    }
  }

  skinware_writer *writer = NULL;
  status = skinware_writer_create(skin, layer, topology, NULL, &writer);
  skinware_topology_free(topology);
  if (status != SKINWARE_OK) return fail("creating the layer", status);

  size_t sensors = (size_t)boards * (size_t)triangles * TAXELS;
  uint16_t *responses = calloc(sensors, sizeof *responses);
  char line[64];
  size_t used = 0;
  uint64_t published = 0, faults = 0, cycle_start = 0, deadline = 0;
  int cycle_fault = 0;
  if (seconds > 0) deadline = skinware_monotonic_ns() + (uint64_t)(seconds * 1e9);
  while (!stopping && (deadline == 0 || skinware_monotonic_ns() < deadline)) {
    struct pollfd ready = {.fd = fd, .events = POLLIN};
    int polled = poll(&ready, 1, 200);
    if (polled <= 0) {
      /* A silent bus: readers must see it, not stale frames as live ones. */
      if (polled == 0) skinware_writer_set_state(writer, SKINWARE_STATE_FAULTED);
      continue;
    }
    char chunk[512];
    ssize_t got = read(fd, chunk, sizeof chunk);
    if (got <= 0) {
      skinware_writer_set_state(writer, SKINWARE_STATE_FAULTED);
      usleep(10000);
      continue;
    }
    for (ssize_t i = 0; i < got; ++i) {
      if (chunk[i] != '\r' && chunk[i] != '\a') {
        if (used < sizeof line) line[used++] = chunk[i];
        continue;
      }
      unsigned id = 0, len = 0;
      uint8_t data[8] = {0};
      int is_frame = parse_frame(line, used, &id, data, &len) == 0;
      used = 0;
      if (!is_frame) continue;
      unsigned class = id >> 8, board = (id >> 4) & 0xF, triangle = id & 0xF;
      /* A head carries 7 taxels (8 bytes); a tail 5 and its mask and error (at least 7). */
      int head = (data[0] & 0x80) == 0;
      if ((class != 3 && class != 4) || len < (head ? 8u : 7u)) continue;
      if (board < 1 || board > (unsigned)boards || triangle >= (unsigned)triangles) continue;
      size_t first = ((size_t)(board - 1) * (size_t)triangles + triangle) * TAXELS;
      if (cycle_start == 0) cycle_start = skinware_monotonic_ns();
      if (head) {
        for (int k = 0; k < 7; ++k) responses[first + (size_t)k] = (uint16_t)(255 - data[1 + k]);
        continue;
      }
      for (int k = 0; k < 5; ++k) responses[first + 7 + (size_t)k] = (uint16_t)(255 - data[1 + k]);
      if (len >= 8 && (data[7] & 0x0F) != 0) cycle_fault = 1;
      /* The last triangle's tail closes a cycle: publish the frame. */
      if (board == (unsigned)boards && triangle == (unsigned)triangles - 1) {
        status = skinware_writer_publish(writer, responses, sensors, cycle_fault ? SKINWARE_FRAME_FAULT : 0,
                                         cycle_start, NULL);
        if (status != SKINWARE_OK) return fail("publishing", status);
        skinware_writer_set_state(writer, cycle_fault ? SKINWARE_STATE_FAULTED : SKINWARE_STATE_RUNNING);
        published++;
        faults += (uint64_t)cycle_fault;
        cycle_fault = 0;
        cycle_start = 0;
      }
    }
  }
  printf("mtb_driver: published %" PRIu64 " frames of %zu taxels (%" PRIu64 " faulted)\n", published, sensors, faults);
  free(responses);
  skinware_writer_close(writer);
  close(fd);
  return 0;
}
