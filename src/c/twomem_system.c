/* The operating-system calls twomem needs and Fortran lacks, called only from the Fortran module
 * twomem_base_system: creating directory trees, atomic renames, removing files, the process id
 * and the peak resident memory, exiting with a chosen status, and the C library's decimal
 * conversion (a Fortran internal read per number was most of reading a large mesh file).
 * Every fallible call returns 0 or an errno value and writes a one-line reason (with strerror)
 * into the caller's buffer; the Fortran side adds the path. */

#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

static int fail(char *msg, size_t cap, int err, const char *what, const char *path)
{
    char reason[256];

    if (strerror_r(err, reason, sizeof reason) != 0) snprintf(reason, sizeof reason, "errno %d", err);
    if (path)
        snprintf(msg, cap, "%s '%s': %s", what, path, reason);
    else
        snprintf(msg, cap, "%s: %s", what, reason);
    return err;
}

/* mkdir for one directory; an existing directory is success, an existing file is not. */
static int make_one(const char *dir)
{
    struct stat st;

    if (mkdir(dir, 0777) == 0) return 0;
    if (errno != EEXIST) return errno;
    if (stat(dir, &st) != 0) return errno;
    return S_ISDIR(st.st_mode) ? 0 : ENOTDIR;
}

/* Like mkdir -p: every missing component of path is created. */
int twomem_sys_make_directories(const char *path, char *msg, size_t cap)
{
    size_t n = strlen(path);
    char *buf;
    int err = 0;

    if (n == 0) return 0;
    if (!(buf = malloc(n + 1))) return fail(msg, cap, ENOMEM, "cannot create directory", NULL);
    memcpy(buf, path, n + 1);
    for (size_t i = 1; i <= n && err == 0; ++i) {
        if (buf[i] != '/' && buf[i] != '\0') continue;
        if (buf[i - 1] == '/') continue; /* root or a doubled slash */
        char saved = buf[i];
        buf[i] = '\0';
        err = make_one(buf);
        if (err) {
            if (saved == '\0')
                fail(msg, cap, err, "cannot create directory", NULL);
            else
                fail(msg, cap, err, "cannot create directory", buf);
        }
        buf[i] = saved;
    }
    free(buf);
    return err;
}

int twomem_sys_rename(const char *from, const char *to, char *msg, size_t cap)
{
    if (rename(from, to) != 0) return fail(msg, cap, errno, "cannot rename to", to);
    return 0;
}

/* A missing file is not an error: removing is how leftovers are cleaned up. */
int twomem_sys_remove(const char *path, char *msg, size_t cap)
{
    if (unlink(path) != 0 && errno != ENOENT) return fail(msg, cap, errno, "cannot remove file", NULL);
    return 0;
}

/* 1 if path names an existing directory, 0 otherwise. */
int twomem_sys_is_directory(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISDIR(st.st_mode);
}

int twomem_sys_exists(const char *path)
{
    struct stat st;

    return stat(path, &st) == 0;
}

/* exit() runs the runtime's destructors, so Fortran units and HDF5 files are flushed. */
void twomem_sys_exit(int code) { exit(code); }

int twomem_sys_getpid(void) { return (int)getpid(); }

/* Keep freed memory in the process for the next allocation. glibc serves blocks above its
 * mmap threshold (at most 32 MiB) with fresh mappings and unmaps them on free, and gives the
 * heap's free top back to the kernel: a run that allocates and frees mesh-sized arrays again
 * and again (a Newton step's vectors, an evaluation's workspaces, the output's gathered
 * copies) then has the kernel zero the same memory each time, which is slow on a virtual
 * machine. With no mmapped blocks and no trimming, a freed block is reused: large runs spend
 * far less time in the kernel, at the price of a somewhat higher peak on small runs
 * (docs/performance.md, "Measurements behind design choices"). Other C libraries keep their
 * own policy. */
void twomem_sys_keep_freed_memory(void)
{
#ifdef __GLIBC__
    mallopt(M_MMAP_MAX, 0);
    mallopt(M_TRIM_THRESHOLD, -1);
#endif
}

/* Hand the free pages of the heap back to the kernel now (glibc's malloc_trim also releases
 * whole free pages inside the heap, not only its top). Under the policy above freed memory
 * stays resident; a phase that frees a large structure for a differently shaped one (the
 * multigrid hierarchies before the algebraic flux's arrays) would otherwise keep both in the
 * resident peak, since the new arrays do not fit the holes the old ones left. Below 16 MiB of
 * free heap it keeps them: the kernel would zero them again when reused, which costs a small
 * run more time than its lower peak is worth; a higher threshold left mid-sized runs with an
 * evaluation's workspaces resident beside the Krylov basis that followed them
 * (docs/performance.md). */
void twomem_sys_return_freed_memory(void)
{
#ifdef __GLIBC__
    if (mallinfo2().fordblks >= ((size_t)16 << 20)) malloc_trim(0);
#endif
}

/* Peak resident memory in KiB: VmHWM of /proc/self/status, which belongs to this process
 * alone. getrusage's ru_maxrss is the fallback; it survives exec, so a twomem started from a
 * large parent (a Python study driver) would report the parent's peak. -1 if neither says. */
int64_t twomem_sys_peak_rss_kib(void)
{
    struct rusage usage;
    FILE *status = fopen("/proc/self/status", "r");

    if (status != NULL) {
        char line[256];
        long long kib = -1;

        while (fgets(line, sizeof line, status) != NULL) {
            if (sscanf(line, "VmHWM: %lld kB", &kib) == 1) break;
        }
        fclose(status);
        if (kib >= 0) return (int64_t)kib;
    }
    if (getrusage(RUSAGE_SELF, &usage) != 0) return -1;
    return (int64_t)usage.ru_maxrss;
}

/* One "Key: value kB" line of a /proc file, in bytes; -1 if absent. */
static long long proc_kib_bytes(const char *file, const char *key)
{
    FILE *f = fopen(file, "r");
    char line[256];
    long long kib = -1;
    size_t n = strlen(key);

    if (f == NULL) return -1;
    while (fgets(line, sizeof line, f) != NULL) {
        if (strncmp(line, key, n) == 0 && line[n] == ':') {
            if (sscanf(line + n + 1, "%lld", &kib) != 1) kib = -1;
            break;
        }
    }
    fclose(f);
    return kib < 0 ? -1 : kib * 1024;
}

/* The first number in a file (cgroup limits); -1 if absent or "max". */
static long long file_number(const char *file)
{
    FILE *f = fopen(file, "r");
    long long v = -1;

    if (f == NULL) return -1;
    if (fscanf(f, "%lld", &v) != 1) v = -1;
    fclose(f);
    return v;
}

static void take(long long *best, char *which, size_t cap, long long value, const char *name)
{
    if (value < 0) return;
    if (*best < 0 || value < *best) {
        *best = value;
        snprintf(which, cap, "%s", name);
    }
}

/* How many more bytes this process may allocate: the least of the memory the kernel reports
 * available (MemAvailable, or MemTotal on kernels without it), the address-space and data
 * rlimits (ulimit -v, ulimit -d) less what the process already maps, and the cgroup's limit
 * (v2 memory.max, v1 memory.limit_in_bytes) less its current use. `which` names the limit that
 * decided. -1 if nothing is known (no /proc, no limits). */
int64_t twomem_sys_memory_allowed(char *which, size_t cap)
{
    long long best = -1, v, used;
    struct rlimit lim;

    if (cap > 0) which[0] = '\0';
    v = proc_kib_bytes("/proc/meminfo", "MemAvailable");
    if (v < 0) v = proc_kib_bytes("/proc/meminfo", "MemTotal");
    take(&best, which, cap, v, "MemAvailable in /proc/meminfo");
    if (getrlimit(RLIMIT_AS, &lim) == 0 && lim.rlim_cur != RLIM_INFINITY) {
        used = proc_kib_bytes("/proc/self/status", "VmSize");
        v = (long long)lim.rlim_cur - (used > 0 ? used : 0);
        take(&best, which, cap, v < 0 ? 0 : v, "address-space limit, ulimit -v");
    }
    if (getrlimit(RLIMIT_DATA, &lim) == 0 && lim.rlim_cur != RLIM_INFINITY) {
        used = proc_kib_bytes("/proc/self/status", "VmData");
        v = (long long)lim.rlim_cur - (used > 0 ? used : 0);
        take(&best, which, cap, v < 0 ? 0 : v, "data-segment limit, ulimit -d");
    }
    v = file_number("/sys/fs/cgroup/memory.max");
    if (v >= 0) {
        used = file_number("/sys/fs/cgroup/memory.current");
        v -= used > 0 ? used : 0;
        take(&best, which, cap, v < 0 ? 0 : v, "cgroup memory.max");
    } else {
        v = file_number("/sys/fs/cgroup/memory/memory.limit_in_bytes");
        /* v1 reports "no limit" as a huge number: keep only limits below 2^60 */
        if (v >= 0 && v < (1LL << 60)) {
            used = file_number("/sys/fs/cgroup/memory/memory.usage_in_bytes");
            v -= used > 0 ? used : 0;
            take(&best, which, cap, v < 0 ? 0 : v, "cgroup memory.limit_in_bytes");
        }
    }
    return (int64_t)best;
}

/* The decimal number text[0..len) as a double, rounded by the C library (libgfortran's own reads
 * convert with strtod too, so the bits are those of a Fortran read); 'd' and 'D' exponents are
 * read as 'e'. The caller has checked the token against its grammar and range. Returns 0, or 1
 * where the token is too long for the buffer or does not convert whole. */
int twomem_sys_parse_double(const char *text, int len, double *value)
{
    char buf[64];
    char *end;
    int i;

    if (len <= 0 || len >= (int)sizeof buf) return 1;
    for (i = 0; i < len; i++) buf[i] = (text[i] == 'd' || text[i] == 'D') ? 'e' : text[i];
    buf[len] = '\0';
    *value = strtod(buf, &end);
    return end == buf + len ? 0 : 1;
}
