/*
 * `skin bench c`'s C side: times skinware_reader_latest() into a caller's
 * buffer, one sample per read, on the layer the Rust side times too.
 *   c_bench SKIN LAYER READS   prints one line per read: nanoseconds
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include <skinware.h>

static unsigned long long now_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (unsigned long long)t.tv_sec * 1000000000ull + (unsigned long long)t.tv_nsec;
}

int main(int argc, char **argv) {
  if (argc < 4 || !skinware_abi_compatible()) {
    fprintf(stderr, "usage: c_bench SKIN LAYER READS (with a libskinware of ABI %d)\n", SKINWARE_ABI_VERSION);
    return 2;
  }
  long reads = strtol(argv[3], NULL, 10);
  skinware_reader *reader = NULL;
  if (skinware_reader_open(argv[1], argv[2], NULL, &reader) != SKINWARE_OK) {
    fprintf(stderr, "c_bench: %s\n", skinware_last_error());
    return 1;
  }
  size_t bytes = 0;
  skinware_reader_payload_bytes(reader, &bytes);
  unsigned short *buffer = malloc(bytes);
  unsigned long long *samples = malloc((size_t)reads * sizeof *samples);
  skinware_frame_info info;
  for (long i = 0; i < reads; ++i) {
    unsigned long long started = now_ns();
    skinware_status status = skinware_reader_latest(reader, buffer, bytes, &info);
    samples[i] = now_ns() - started;
    if (status != SKINWARE_OK) {
      fprintf(stderr, "c_bench: %s\n", skinware_last_error());
      return 1;
    }
  }
  for (long i = 0; i < reads; ++i) printf("%llu\n", samples[i]);
  free(samples);
  free(buffer);
  skinware_reader_close(reader);
  return 0;
}
