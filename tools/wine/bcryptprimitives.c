/*
 * A stand-in for Windows' bcryptprimitives.dll, for running the Windows builds under Wine 8
 * (Debian 12), which lacks it. Rust's standard library takes its random bytes (HashMap keys)
 * from ProcessPrng in that DLL; Windows 10 and later have it. This one answers from
 * RtlGenRandom (advapi32's SystemFunction036), which Wine has. Test harness only: it is put
 * next to the .exe files that scripts/test runs under Wine, never shipped.
 */
#include <windows.h>

BOOLEAN WINAPI SystemFunction036(PVOID buffer, ULONG length);

__declspec(dllexport) BOOL WINAPI ProcessPrng(PBYTE data, SIZE_T length)
{
    while (length > 0) {
        ULONG chunk = length > 0x10000000 ? 0x10000000 : (ULONG)length;
        if (!SystemFunction036(data, chunk)) {
            return FALSE;
        }
        data += chunk;
        length -= chunk;
    }
    return TRUE;
}
