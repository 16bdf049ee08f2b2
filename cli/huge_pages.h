/* huge_pages.h — transparent huge pages for what malloc maps (cli/huge_pages.c). */
#ifndef NS_CLI_HUGE_PAGES_H
#define NS_CLI_HUGE_PAGES_H

#include <stddef.h>

/* Starts this process again with glibc's tunable glibc.malloc.hugetlb=1 in its environment
 * unless GLIBC_TUNABLES is set already (the user's own setting stays theirs),
 * NSCATTER_HUGE_PAGES=0, it is the restarted process, or it runs in secure mode or through
 * the dynamic loader named as the program; returns only when it did not (or could not): 0,
 * or -1 when NSCATTER_HUGE_PAGES is neither 0 nor 1 (nothing done). */
int huge_pages_start(char **argv);

/* Whether GLIBC_TUNABLES holds glibc.malloc.hugetlb=1 (what glibc then does is glibc's: a
 * sanitizer's allocator, or a glibc before 2.35, ignores it). */
int huge_pages_on(void);

/* The kernel's transparent huge page mode (always, madvise or never), or "unknown". */
const char *huge_pages_kernel_mode(char *buf, size_t size);

#endif
