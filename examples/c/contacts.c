/*
 * A C reader that prints contacts: attaches to a running skin's contact
 * service and prints, for every new frame, each region's contacts.
 *
 *   skin run examples/demo.toml &           # the demo skin, with its contact service
 *   ./contacts default contact 50           # skin, service, frames to print (0: forever)
 *
 * Build: cc contacts.c $(pkg-config --cflags --libs skinware) -o contacts
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>

#include <skinware.h>

static int fail(const char *what, skinware_status status) {
  fprintf(stderr, "%s: %s: %s\n", what, skinware_status_name(status), skinware_last_error());
  return 1;
}

int main(int argc, char **argv) {
  const char *skin = argc > 1 ? argv[1] : "default";
  const char *service = argc > 2 ? argv[2] : "contact";
  long frames = argc > 3 ? strtol(argv[3], NULL, 10) : 0;
  if (!skinware_abi_compatible()) {
    fprintf(stderr, "libskinware has C ABI %u, this program was built for %u: rebuild it\n",
            skinware_abi_version(), SKINWARE_ABI_VERSION);
    return 1;
  }

  skinware_reader *reader = NULL;
  skinware_status status = skinware_contacts_open(skin, service, NULL, &reader);
  if (status != SKINWARE_OK) return fail("opening the contact service", status);

  skinware_channel_description description;
  status = skinware_reader_describe(reader, &description);
  if (status != SKINWARE_OK) return fail("describing it", status);
  size_t regions = description.values;
  skinware_region_contacts *records = calloc(regions, sizeof *records);
  if (records == NULL) return fail("allocating", SKINWARE_E_INVALID_ARGUMENT);
  printf("%s/%s: %zu regions\n", skin, service, regions);

  int result = 0;
  for (long printed = 0; frames == 0 || printed < frames; ++printed) {
    skinware_frame_info info;
    status = skinware_reader_wait_newer(reader, SKINWARE_DEFAULT_TIMEOUT_NS, records,
                                        regions * sizeof *records, &info);
    if (status != SKINWARE_OK) {
      result = fail("waiting for contacts", status);
      break;
    }
    printf("frame %" PRIu64 " (%" PRIu64 " skipped)%s\n", info.seq, info.skipped,
           (info.status & SKINWARE_FRAME_FAULT) ? " FAULT" : "");
    for (size_t r = 0; r < regions; ++r) {
      const char *label = "";
      if (skinware_reader_label(reader, r, &label) != SKINWARE_OK) label = "?";
      for (uint32_t c = 0; c < records[r].count && c < SKINWARE_MAX_CONTACTS; ++c) {
        const skinware_contact *contact = &records[r].contacts[c];
        printf("  %-12s contact %u: %3u taxels, peak %6.1f at sensor %u, centroid (%.3f, %.3f, %.3f) m\n",
               label, c, contact->taxels, contact->peak, contact->peak_sensor, contact->centroid[0],
               contact->centroid[1], contact->centroid[2]);
      }
    }
  }
  free(records);
  skinware_reader_close(reader);
  return result;
}
