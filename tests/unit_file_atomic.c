/* unit_file_atomic.c — ns_write_file_atomic and ns_write_file_atomic_parts (nscatter.h):
 * the bytes arrive whole, an existing file is replaced, and every failure (no folder, a
 * write cut short, a rename refused) leaves what was there before and no temporary file. */
#include <dirent.h>
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "harness.h"
#include "nscatter.h"

static char dir[256];

static void path_in_dir(char *out, size_t cap, const char *name)
{
    snprintf(out, cap, "%s/%s", dir, name);
}

/* The whole file, NUL-terminated; *size its length, or (size_t)-1 when it cannot be read. */
static char *slurp(const char *path, size_t *size)
{
    static char buf[1 << 16];
    *size = (size_t)-1;
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    *size = fread(buf, 1, sizeof buf - 1, f);
    buf[*size] = 0;
    fclose(f);
    return buf;
}

static void write_plain(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

/* Files in the folder whose name holds ".tmp.": what a failed write must not leave. */
static int temporaries(void)
{
    int n = 0;
    DIR *d = opendir(dir);
    for (struct dirent *e; d && (e = readdir(d));)
        n += strstr(e->d_name, ".tmp.") != NULL;
    if (d)
        closedir(d);
    return n;
}

static void test_writes_and_replaces(void)
{
    char path[512];
    path_in_dir(path, sizeof path, "a.bin");
    ns_error err = {0};
    CHECK_INT(ns_write_file_atomic(path, "first", 5, &err), NS_OK);
    size_t size;
    CHECK(!strcmp(slurp(path, &size), "first") && size == 5);
    struct stat st;
    CHECK(stat(path, &st) == 0 && (st.st_mode & 0777) == 0644);
    CHECK_INT(ns_write_file_atomic(path, "second, longer", 14, &err), NS_OK);
    CHECK(!strcmp(slurp(path, &size), "second, longer") && size == 14);
    /* Shorter than before: the old tail must not survive (a new file, not an overwrite). */
    CHECK_INT(ns_write_file_atomic(path, "3", 1, &err), NS_OK);
    CHECK(!strcmp(slurp(path, &size), "3") && size == 1);
    /* Empty: a file of no bytes, data may be NULL. */
    CHECK_INT(ns_write_file_atomic(path, NULL, 0, &err), NS_OK);
    CHECK(slurp(path, &size) && size == 0);
    CHECK_INT(temporaries(), 0);
    unlink(path);
}

static void test_parts(void)
{
    char path[512];
    path_in_dir(path, sizeof path, "parts.txt");
    const ns_file_part parts[] = {{"head|", 5}, {NULL, 0}, {"body", 4}, {"\n", 1}};
    CHECK_INT(ns_write_file_atomic_parts(path, parts, 4, NULL), NS_OK);
    size_t size;
    CHECK(!strcmp(slurp(path, &size), "head|body\n"));
    CHECK_INT(ns_write_file_atomic_parts(path, parts, 0, NULL), NS_OK); /* no parts: empty */
    CHECK(slurp(path, &size) && size == 0);
    /* Bigger than one write() may take at once. */
    size_t big = 3u << 20;
    char *data = malloc(big);
    for (size_t i = 0; data && i < big; i++)
        data[i] = (char)(i * 7);
    CHECK_INT(ns_write_file_atomic(path, data, big, NULL), NS_OK);
    struct stat st;
    CHECK(stat(path, &st) == 0 && (size_t)st.st_size == big);
    FILE *f = fopen(path, "rb");
    char *back = malloc(big);
    CHECK(f && back && fread(back, 1, big, f) == big && !memcmp(back, data, big));
    if (f)
        fclose(f);
    free(back);
    free(data);
    unlink(path);
    CHECK_INT(temporaries(), 0);
}

static void test_missing_folder(void)
{
    char path[512];
    path_in_dir(path, sizeof path, "no-such-folder/x.png");
    ns_error err = {0};
    CHECK_INT(ns_write_file_atomic(path, "x", 1, &err), NS_ERR_IO);
    CHECK_INT(err.status, NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, "no-such-folder/x.png");
    CHECK_STR_CONTAINS(err.message, strerror(ENOENT));
    CHECK_INT(errno, ENOENT); /* for callers that print strerror(errno) */
    CHECK_INT(ns_write_file_atomic(path, "x", 1, NULL), NS_ERR_IO); /* err may be NULL */
}

/* A rename over a folder fails (EISDIR or ENOTEMPTY): what was at the path stays, with its
 * contents, and the temporary file is gone. */
static void test_failed_rename_keeps_old(void)
{
    char path[512], inside[600];
    path_in_dir(path, sizeof path, "occupied");
    CHECK(mkdir(path, 0755) == 0);
    snprintf(inside, sizeof inside, "%s/old.txt", path);
    write_plain(inside, "old contents");
    ns_error err = {0};
    CHECK_INT(ns_write_file_atomic(path, "new", 3, &err), NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, "cannot replace");
    CHECK_STR_CONTAINS(err.message, path);
    size_t size;
    const char *old = slurp(inside, &size);
    CHECK(old && !strcmp(old, "old contents"));
    struct stat st;
    CHECK(stat(path, &st) == 0 && S_ISDIR(st.st_mode));
    CHECK_INT(temporaries(), 0);
    unlink(inside);
    rmdir(path);
}

/* A write cut short (here by the file size limit, EFBIG: a full disk behaves alike) leaves
 * the old file whole, and no temporary file. The limit binds root too. */
static void test_failed_write_keeps_old(void)
{
    char path[512];
    path_in_dir(path, sizeof path, "kept.txt");
    write_plain(path, "the earlier file");
    struct rlimit saved, small = {64, 64};
    CHECK(getrlimit(RLIMIT_FSIZE, &saved) == 0);
    small.rlim_max = saved.rlim_max; /* lowering only the soft limit can be undone */
    void (*old_handler)(int) = signal(SIGXFSZ, SIG_IGN);
    CHECK(setrlimit(RLIMIT_FSIZE, &small) == 0);
    char big[4096];
    memset(big, 'n', sizeof big);
    ns_error err = {0};
    int rc = ns_write_file_atomic(path, big, sizeof big, &err);
    setrlimit(RLIMIT_FSIZE, &saved);
    signal(SIGXFSZ, old_handler);
    CHECK_INT(rc, NS_ERR_IO);
    CHECK_STR_CONTAINS(err.message, "cannot write");
    CHECK_STR_CONTAINS(err.message, path);
    size_t size;
    const char *kept = slurp(path, &size);
    CHECK(kept && !strcmp(kept, "the earlier file"));
    CHECK_INT(temporaries(), 0);
    unlink(path);
}

/* A bare file name: the temporary file and the folder flush use the current folder. */
static void test_relative_path(void)
{
    char cwd[1024];
    CHECK(getcwd(cwd, sizeof cwd) != NULL);
    CHECK(chdir(dir) == 0);
    CHECK_INT(ns_write_file_atomic("plain.txt", "here", 4, NULL), NS_OK);
    size_t size;
    CHECK(!strcmp(slurp("plain.txt", &size), "here"));
    unlink("plain.txt");
    CHECK(chdir(cwd) == 0);
    CHECK_INT(temporaries(), 0);
}

int main(void)
{
    snprintf(dir, sizeof dir, "/tmp/ns_file_atomic_XXXXXX");
    if (!mkdtemp(dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(test_writes_and_replaces);
    RUN(test_parts);
    RUN(test_missing_folder);
    RUN(test_failed_rename_keeps_old);
    RUN(test_failed_write_keeps_old);
    RUN(test_relative_path);
    rmdir(dir);
    return harness_report();
}
