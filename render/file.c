/* file.c — files written atomically (nscatter.h): the one copy of "temporary file, fsync,
 * rename" that the pipeline cache, the network weights, the scattering tables, the training
 * checkpoints, the bench cache and rendered images all use; and the cache folder on disk. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "nscatter.h"

/* Writes all of [data, data + size) to fd; 0, or -1 with errno set. */
static int write_all(int fd, const char *data, size_t size)
{
    while (size > 0) {
        ssize_t n = write(fd, data, size);
        if (n < 0 && errno == EINTR)
            continue;
        if (n < 0)
            return -1;
        if (n == 0) {
            errno = EIO; /* a regular file never takes nothing; do not loop forever */
            return -1;
        }
        data += n;
        size -= (size_t)n;
    }
    return 0;
}

/* The rename is recorded in the folder, not in the file: without flushing the folder too, a
 * crash soon after could bring back the old name. Best effort: the rename has happened, and a
 * file system that cannot flush a folder (some network ones) must not fail the write. */
static void fsync_parent(const char *path)
{
    const char *slash = strrchr(path, '/');
    char *dir = slash ? strndup(path, slash == path ? 1 : (size_t)(slash - path)) : strdup(".");
    if (!dir)
        return;
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    if (fd >= 0) {
        fsync(fd);
        close(fd);
    }
    free(dir);
}

/* NS_ERR_IO with "<what> '<path>': <reason>", and errno left as the failing call set it,
 * for callers that report strerror(errno) themselves. */
static int fail(ns_error *err, int e, const char *what, const char *path)
{
    int status = ns_fail(err, NS_ERR_IO, "%s '%s': %s", what, path, strerror(e));
    errno = e;
    return status;
}

int ns_write_file_atomic_parts(const char *path, const ns_file_part *parts, size_t count,
                               ns_error *err)
{
    /* A name of its own (mkstemp), not a fixed PATH.part: two processes that write the same
     * cache file at once must not write into each other's temporary file. */
    size_t tmp_size = strlen(path) + sizeof ".tmp.XXXXXX";
    char *tmp = malloc(tmp_size);
    if (!tmp)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "cannot write '%s': out of memory", path);
    snprintf(tmp, tmp_size, "%s.tmp.XXXXXX", path);
    int fd = mkstemp(tmp);
    if (fd < 0) {
        int e = errno;
        free(tmp);
        return fail(err, e, "cannot create a file beside", path);
    }
    /* mkstemp makes the file private (0600); what is written here (images, tables, weights,
     * caches) is meant to be read like any other file. */
    int ok = fchmod(fd, 0644) == 0;
    for (size_t i = 0; ok && i < count; i++)
        ok = write_all(fd, parts[i].data, parts[i].size) == 0;
    /* fsync before the rename: otherwise a crash can leave the new name on an empty file. */
    ok = ok && fsync(fd) == 0;
    int e = errno;
    if (close(fd) != 0 && ok) {
        ok = 0;
        e = errno;
    }
    if (!ok) {
        unlink(tmp);
        free(tmp);
        return fail(err, e, "cannot write", path);
    }
    if (rename(tmp, path) != 0) {
        e = errno;
        unlink(tmp);
        free(tmp);
        return fail(err, e, "cannot replace", path);
    }
    free(tmp);
    fsync_parent(path);
    return NS_OK;
}

int ns_write_file_atomic(const char *path, const void *data, size_t size, ns_error *err)
{
    const ns_file_part part = {data, size};
    return ns_write_file_atomic_parts(path, &part, 1, err);
}

int ns_cache_dir(const char *given, const char *what, char *dir, size_t cap, ns_error *err)
{
    const char *env = getenv("NSCATTER_CACHE_DIR");
    const char *xdg = getenv("XDG_CACHE_HOME");
    const char *home = getenv("HOME");
    int n;
    if (given && *given)
        n = snprintf(dir, cap, "%s", given);
    else if (env && *env)
        n = snprintf(dir, cap, "%s", env);
    else if (xdg && *xdg)
        n = snprintf(dir, cap, "%s/nscatter", xdg);
    else if (home && *home)
        n = snprintf(dir, cap, "%s/.cache/nscatter", home);
    else
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT,
                       "%s: set NSCATTER_CACHE_DIR (no XDG_CACHE_HOME or HOME)", what);
    if (n < 0 || (size_t)n >= cap)
        return ns_fail(err, NS_ERR_INVALID_ARGUMENT, "%s: directory name too long", what);
    return NS_OK;
}

int ns_make_dirs(const char *dir, const char *what, ns_error *err)
{
    size_t len = strlen(dir);
    char *path = malloc(len + 1);
    if (!path)
        return ns_fail(err, NS_ERR_OUT_OF_HOST_MEMORY, "%s: out of memory", what);
    memcpy(path, dir, len + 1);
    int status = NS_OK;
    for (char *p = path + 1; len > 0; p++) {
        if (*p != '/' && *p != '\0')
            continue;
        char saved = *p;
        *p = '\0';
        if (mkdir(path, 0755) != 0 && errno != EEXIST) {
            status = ns_fail(err, NS_ERR_IO, "%s: cannot create '%s': %s", what, path, strerror(errno));
            break;
        }
        *p = saved;
        if (saved == '\0')
            break;
    }
    free(path);
    struct stat st;
    if (!status && (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode)))
        status = ns_fail(err, NS_ERR_IO, "%s: '%s' is not a directory", what, dir);
    return status;
}
