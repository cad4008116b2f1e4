/* Codec harness for tests/cfirmware: one request per stdin line, one answer per stdout line.
 *   "P TYPE HEX"  decode a payload of message type TYPE (decimal) -> "OK <dump> | <re-encoded hex>" or "ERR <code> <why>"
 *   "C HEX"       COBS-decode a block -> "OK <hex>" or "ERR"
 *   "R HEX"       CRC-16/X-25 of the bytes -> "<crc decimal>"
 * Built with GS_PROTO_DUMP and ASan/UBSan (firmware_sim.cfirmware.build kind "codec"). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gs_cobs.h"
#include "gs_crc.h"
#include "gs_proto.h"
#include "gs_hex.h"

int main(void) {
    static char line[8192];
    static uint8_t buf[4096], out[4096];
    static char dump[16384];
    while (fgets(line, sizeof line, stdin)) {
        if (line[0] == 'P') {
            unsigned type;
            char *sp;
            if (sscanf(line + 2, "%u", &type) != 1 || !(sp = strchr(line + 2, ' '))) {
                printf("BAD\n");
            } else {
                int n = gs_unhex(sp + 1, buf, sizeof buf);
                gs_msg_t m;
                const char *why = "";
                int rc = n < 0 ? GS_E_VALUE : gs_decode_payload((uint8_t)type, buf, (size_t)n, &m, &why);
                if (rc != GS_OK) {
                    printf("ERR %d %s\n", rc, why);
                } else {
                    gs_dump_msg(&m, dump, sizeof dump);
                    int k = gs_encode_payload(&m, out, sizeof out);
                    printf("OK %s | ", dump);
                    if (k >= 0) gs_print_hex(out, (size_t)k);
                    else printf("ENC%d", k);
                    printf("\n");
                }
            }
        } else if (line[0] == 'C') {
            int n = gs_unhex(line + 2, buf, sizeof buf);
            long k = n < 0 ? -1 : gs_cobs_decode(buf, (size_t)n);
            if (k < 0) printf("ERR\n");
            else { printf("OK "); gs_print_hex(buf, (size_t)k); printf("\n"); }
        } else if (line[0] == 'R') {
            int n = gs_unhex(line + 2, buf, sizeof buf);
            printf("%u\n", n < 0 ? 0u : (unsigned)gs_crc16_x25(buf, (size_t)n));
        } else {
            printf("BAD\n");
        }
        fflush(stdout);
    }
    return 0;
}
