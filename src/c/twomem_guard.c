/* How a run ends when it is not allowed to finish: SIGTERM or SIGINT (a job scheduler, Ctrl-C)
 * and an allocation that fails after the up-front memory check. Called only from the Fortran
 * module twomem_base_system.
 *
 * Signals. The handler removes the temporary result file registered below (if any), writes one
 * line and _exit()s with 128 + signo: unlink, write and _exit are async-signal-safe, and nothing
 * else is done in the handler. The other design, a sig_atomic_t flag polled at safe points, was
 * rejected: a direct solve (one UMFPACK factorization can take minutes) or an estimator
 * evaluation has no safe point inside, so the run would not stop promptly; and under MPI the
 * ranks see the signal at different iterations, so every poll would have to be a collective
 * (an allreduce per GMRES iteration) to avoid one rank leaving a collective the others are in.
 * Ending the process at once needs no agreement: mpirun delivers SIGTERM to every rank and each
 * one ends itself (a rank killed alone makes mpirun end the others). Nothing half-written
 * survives because the only file a run writes is created under a temporary name, registered
 * here before it is created, and renamed over the result only when complete: the handler
 * removes the temporary, and an older result of the same name is never touched.
 *
 * Out of memory. gfortran compiles ALLOCATE without STAT= (and the heap temporaries of array
 * expressions) into malloc followed, on failure, by a call to libgfortran's
 * _gfortran_os_error_at, which prints a backtrace and exits with status 1, the code twomem
 * reserves for "did not converge". Defining that function here makes the dynamic linker bind
 * every such call in the executable to this definition (the executable comes first in symbol
 * lookup), so each of the hundreds of allocations in the code ends with one line and exit 3.
 * Putting STAT= on each allocation would cover only the ones edited and make every caller
 * handle an error it cannot act on. The cost: the name is libgfortran's (stable since GCC 10,
 * GFORTRAN_10 symbol version); if it changes, a failure falls back to gfortran's own message,
 * and the regression test test_resources.py notices. */

#define _POSIX_C_SOURCE 200809L

#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#define TMP_CAP 4096

/* the registered temporary path; tmp_set says whether tmp_path holds a complete name */
static char tmp_path[TMP_CAP];
static volatile sig_atomic_t tmp_set = 0;
/* whether this process prints the interruption line (rank 0 only: one line per run) */
static volatile sig_atomic_t print_signal = 1;

static void write_all(int fd, const char *text, size_t n)
{
    while (n > 0) {
        ssize_t k = write(fd, text, n);
        if (k <= 0) return;
        text += k;
        n -= (size_t)k;
    }
}

static void on_signal(int signo)
{
    static const char term[] = "twomem: interrupted by SIGTERM\n";
    static const char intr[] = "twomem: interrupted by SIGINT\n";

    if (tmp_set) unlink(tmp_path);
    if (print_signal) {
        if (signo == SIGTERM)
            write_all(2, term, sizeof term - 1);
        else
            write_all(2, intr, sizeof intr - 1);
    }
    _exit(128 + signo);
}

/* Install the handlers for SIGTERM and SIGINT; `print` = 0 keeps this process quiet. A signal
 * ignored when the program started (nohup, a shell's background job for SIGINT) stays ignored,
 * as POSIX asks of programs that catch signals. Returns 0 or an errno value. */
int twomem_guard_install(int print)
{
    static const int signals[2] = {SIGTERM, SIGINT};

    print_signal = print != 0;
    for (int i = 0; i < 2; ++i) {
        struct sigaction old, act;

        if (sigaction(signals[i], NULL, &old) != 0) return -1;
        if (old.sa_handler == SIG_IGN) continue;
        memset(&act, 0, sizeof act);
        act.sa_handler = on_signal;
        sigfillset(&act.sa_mask);
        if (sigaction(signals[i], &act, NULL) != 0) return -1;
    }
    return 0;
}

/* Signals blocked while the registered name changes, so the handler never sees half a name. */
static void block(sigset_t *saved)
{
    sigset_t set;

    sigemptyset(&set);
    sigaddset(&set, SIGTERM);
    sigaddset(&set, SIGINT);
    sigprocmask(SIG_BLOCK, &set, saved);
}

/* Register `path` (before creating it) as the file to remove if the run ends now. One at a
 * time: a run writes its temporaries one after the other. 0, or -1 if the path is too long to
 * register (the caller then writes anyway: only the clean-up on a signal is lost). */
int twomem_guard_register(const char *path)
{
    sigset_t saved;
    size_t n = strlen(path);

    if (n >= TMP_CAP) return -1;
    block(&saved);
    tmp_set = 0;
    memcpy(tmp_path, path, n + 1);
    tmp_set = 1;
    sigprocmask(SIG_SETMASK, &saved, NULL);
    return 0;
}

/* After the rename (or the removal): nothing left to clean up. */
void twomem_guard_unregister(void)
{
    sigset_t saved;

    block(&saved);
    tmp_set = 0;
    sigprocmask(SIG_SETMASK, &saved, NULL);
}

/* Called by gfortran-compiled code when an allocation fails (see the top of the file). `where`
 * is "In file 'x.f90', around line N", `format` "Error allocating %lu bytes". */
void _gfortran_os_error_at(const char *where, const char *format, ...)
{
    char what[256], line[640];
    va_list args;
    int n;

    va_start(args, format);
    vsnprintf(what, sizeof what, format, args);
    va_end(args);
    if (tmp_set) unlink(tmp_path);
    n = snprintf(line, sizeof line, "twomem: error: out of memory: %s (%s); see 'Memory' in docs/robustness.md\n",
                 what, where ? where : "unknown place");
    if (n > 0) write_all(2, line, (size_t)n < sizeof line ? (size_t)n : sizeof line - 1);
    _exit(3);
}
