/* huge_pages.c — transparent huge pages for what malloc maps.
 *
 * A render allocates large buffers afresh and touches them once: a material's tables (six of
 * 10.6 MB from the networks, their sums, the texels the accumulation reads, A), lavapipe's
 * device memory behind every buffer and image, the camera segments. With 4 KiB pages each
 * first touch faults once per page (on the 2-core VM a fault with its zeroing costs
 * microseconds), and reconstructing a material's tables spent a third of its time there.
 * glibc's tunable glibc.malloc.hugetlb=1 has malloc advise MADV_HUGEPAGE on what it maps,
 * so that where the kernel's mode is "madvise" (Debian's and most distributions' default)
 * those regions fault once per 2 MiB. Measured (docs/bench.md, *Huge pages*): the bench's
 * scenes at 256², cold, reconstruct −19 to −45%, accumulate −8 to −16%, whole renders up to
 * −21%, the images the same.
 *
 * glibc reads its tunables only when a process starts, and lavapipe allocates through malloc
 * inside the driver, where no madvise of ours reaches: so main() starts the binary again
 * with the tunable set, once (execv keeps the pid, the arguments and the open files). */
#define _GNU_SOURCE
#include "huge_pages.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/auxv.h>
#include <unistd.h>

#define HUGE_PAGES_TUNABLE "glibc.malloc.hugetlb=1"
/* Set in the restarted process: it never restarts again, whatever glibc did to
 * GLIBC_TUNABLES (a secure-mode process may find it scrubbed). */
#define HUGE_PAGES_RESTARTED "NSCATTER_HUGE_PAGES_RESTARTED"

int huge_pages_start(char **argv)
{
    const char *want = getenv("NSCATTER_HUGE_PAGES");
    if (want && strcmp(want, "0") && strcmp(want, "1"))
        return -1;
    if (getenv("GLIBC_TUNABLES") || getenv(HUGE_PAGES_RESTARTED) || (want && !strcmp(want, "0")))
        return 0;
    /* Not in secure mode (set-user-ID, file capabilities: glibc ignores the tunables there),
     * nor when the binary was started through the dynamic loader named as the program
     * (AT_BASE 0), where /proc/self/exe is the loader, not nscatter. */
    if (getauxval(AT_SECURE) || !getauxval(AT_BASE))
        return 0;
    if (setenv(HUGE_PAGES_RESTARTED, "1", 1) || setenv("GLIBC_TUNABLES", HUGE_PAGES_TUNABLE, 1))
        return 0;
    execv("/proc/self/exe", argv);
    /* No /proc (or no exec): go on with the pages as they are. */
    unsetenv("GLIBC_TUNABLES");
    unsetenv(HUGE_PAGES_RESTARTED);
    return 0;
}

int huge_pages_on(void)
{
    const char *t = getenv("GLIBC_TUNABLES");
    /* The tunables are name=value pairs separated by colons. */
    for (const char *p = t; p && *p;) {
        size_t n = strcspn(p, ":");
        if (n == strlen(HUGE_PAGES_TUNABLE) && !strncmp(p, HUGE_PAGES_TUNABLE, n))
            return 1;
        p += n + (p[n] == ':');
    }
    return 0;
}

const char *huge_pages_kernel_mode(char *buf, size_t size)
{
    snprintf(buf, size, "unknown");
    FILE *f = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
    if (!f)
        return buf;
    char line[128];
    if (fgets(line, sizeof line, f)) {
        /* "always [madvise] never": the bracketed word is the mode. */
        char *a = strchr(line, '['), *b = a ? strchr(a, ']') : NULL;
        if (a && b && (size_t)(b - a - 1) < size)
            snprintf(buf, size, "%.*s", (int)(b - a - 1), a + 1);
    }
    fclose(f);
    return buf;
}
