/* The HDF5 side of twomem's files (results, nodal loads), called only from the Fortran module
 * twomem_hdf5_file.
 * Every entry point returns a status (0 = success) and, on failure, writes a one-line message
 * into the caller's buffer: the HDF5 error stack's outermost description (what the API call
 * was asked to do) followed by its innermost one (the actual cause, e.g. the errno of open(2)).
 * HDF5's own printing of the stack is switched off, so nothing reaches stderr behind the
 * program's back. Dimensions are HDF5's (row-major) dims: the Fortran side passes its shape
 * reversed, so that a Fortran a(2, nv) is read by h5py as (nv, 2) without a transposing copy.
 * Datasets are contiguous (no chunking, no filters) so that XDMF readers can map them directly. */

#include <hdf5.h>

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

_Static_assert(sizeof(hid_t) == sizeof(int64_t), "hid_t must be 64-bit (HDF5 >= 1.10)");

enum { STATUS_OK = 0, STATUS_HDF5 = 1, STATUS_MISMATCH = 2, STATUS_NOMEM = 3 };
enum { MAX_RANK = 7 };

/* ---- error messages --------------------------------------------------------------------- */

typedef struct {
    char outer[512];
    char inner[1024];
    unsigned count;
} stack_walk_t;

static void copy_text(char *dst, size_t cap, const char *src)
{
    if (cap == 0) return;
    snprintf(dst, cap, "%s", src ? src : "");
    /* the caller promises one line */
    for (char *p = dst; *p; ++p)
        if (*p == '\n' || *p == '\r' || *p == '\t') *p = ' ';
}

static herr_t collect_entry(unsigned n, const H5E_error2_t *e, void *data)
{
    stack_walk_t *w = data;
    char text[1024];

    if (e->desc && e->desc[0]) {
        copy_text(text, sizeof text, e->desc);
    } else if (H5Eget_msg(e->min_num, NULL, text, sizeof text) < 0) {
        text[0] = '\0';
    }
    if (n == 0) copy_text(w->outer, sizeof w->outer, text);
    copy_text(w->inner, sizeof w->inner, text);
    w->count = n + 1;
    return 0;
}

/* Must run right after the failing call: the next API call clears the stack. */
static int fail_hdf5(char *msg, size_t cap, const char *fallback)
{
    stack_walk_t w = {.outer = "", .inner = "", .count = 0};

    H5Ewalk2(H5E_DEFAULT, H5E_WALK_DOWNWARD, collect_entry, &w);
    if (w.count == 0)
        snprintf(msg, cap, "HDF5: %s", fallback);
    else if (w.count == 1 || strcmp(w.outer, w.inner) == 0)
        snprintf(msg, cap, "HDF5: %s", w.outer);
    else
        snprintf(msg, cap, "HDF5: %s (%s)", w.outer, w.inner);
    H5Eclear2(H5E_DEFAULT);
    return STATUS_HDF5;
}

static int fail_text(char *msg, size_t cap, int status, const char *text)
{
    snprintf(msg, cap, "%s", text);
    return status;
}

static void quiet(void) { H5Eset_auto2(H5E_DEFAULT, NULL, NULL); }

static void close_id(hid_t id, herr_t (*closer)(hid_t))
{
    if (id >= 0) closer(id);
}

/* ---- files ------------------------------------------------------------------------------ */

int twomem_h5_create(const char *path, int64_t *fid, char *msg, size_t cap)
{
    quiet();
    *fid = H5Fcreate(path, H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    if (*fid < 0) return fail_hdf5(msg, cap, "unable to create file");
    return STATUS_OK;
}

int twomem_h5_open_read(const char *path, int64_t *fid, char *msg, size_t cap)
{
    quiet();
    *fid = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
    if (*fid < 0) return fail_hdf5(msg, cap, "unable to open file");
    return STATUS_OK;
}

int twomem_h5_close(int64_t fid, char *msg, size_t cap)
{
    quiet();
    if (H5Fclose(fid) < 0) return fail_hdf5(msg, cap, "unable to close file");
    return STATUS_OK;
}

/* ---- existence -------------------------------------------------------------------------- */

/* H5Lexists fails (rather than answering 0) when an intermediate group is missing, so walk
 * the path one component at a time. */
static int path_exists(hid_t fid, const char *path)
{
    size_t n = strlen(path);
    char *buf;
    int found = 1;

    if (n == 0) return 0;
    buf = malloc(n + 1);
    if (!buf) return 0;
    memcpy(buf, path, n + 1);
    for (size_t i = 1; i <= n && found; ++i) {
        if (buf[i] != '/' && buf[i] != '\0') continue;
        if (buf[i - 1] == '/') continue; /* root or a doubled slash */
        char saved = buf[i];
        buf[i] = '\0';
        found = H5Lexists(fid, buf, H5P_DEFAULT) > 0;
        buf[i] = saved;
    }
    free(buf);
    return found;
}

int twomem_h5_exists(int64_t fid, const char *path)
{
    quiet();
    if (strcmp(path, "/") == 0) return 1;
    return path_exists(fid, path);
}

int twomem_h5_attr_exists(int64_t fid, const char *obj, const char *name)
{
    quiet();
    if (strcmp(obj, "/") != 0 && !path_exists(fid, obj)) return 0;
    return H5Aexists_by_name(fid, obj, name, H5P_DEFAULT) > 0;
}

/* ---- datasets --------------------------------------------------------------------------- */

static int write_dataset(hid_t fid, const char *path, int rank, const int64_t *dims,
                         hid_t file_type, hid_t mem_type, const void *data, char *msg, size_t cap)
{
    hsize_t hdims[MAX_RANK];
    hid_t lcpl = -1, space = -1, dset = -1;
    int status = STATUS_OK;

    quiet();
    if (rank < 1 || rank > MAX_RANK) return fail_text(msg, cap, STATUS_MISMATCH, "unsupported rank");
    for (int i = 0; i < rank; ++i) hdims[i] = (hsize_t)dims[i];

    /* rewriting a dataset replaces it (its shape may have changed) */
    if (path_exists(fid, path) && H5Ldelete(fid, path, H5P_DEFAULT) < 0) {
        status = fail_hdf5(msg, cap, "unable to replace dataset");
        goto done;
    }
    if ((lcpl = H5Pcreate(H5P_LINK_CREATE)) < 0 || H5Pset_create_intermediate_group(lcpl, 1) < 0) {
        status = fail_hdf5(msg, cap, "unable to set up link creation");
        goto done;
    }
    if ((space = H5Screate_simple(rank, hdims, NULL)) < 0) {
        status = fail_hdf5(msg, cap, "unable to create dataspace");
        goto done;
    }
    if ((dset = H5Dcreate2(fid, path, file_type, space, lcpl, H5P_DEFAULT, H5P_DEFAULT)) < 0) {
        status = fail_hdf5(msg, cap, "unable to create dataset");
        goto done;
    }
    if (H5Dwrite(dset, mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0) {
        status = fail_hdf5(msg, cap, "unable to write dataset");
        goto done;
    }
done:
    close_id(dset, H5Dclose);
    close_id(space, H5Sclose);
    close_id(lcpl, H5Pclose);
    return status;
}

int twomem_h5_write_double(int64_t fid, const char *path, int rank, const int64_t *dims,
                           const double *data, char *msg, size_t cap)
{
    return write_dataset(fid, path, rank, dims, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, data, msg, cap);
}

int twomem_h5_write_int(int64_t fid, const char *path, int rank, const int64_t *dims,
                        const int *data, char *msg, size_t cap)
{
    return write_dataset(fid, path, rank, dims, H5T_STD_I32LE, H5T_NATIVE_INT, data, msg, cap);
}

/* Rank and dims of a dataset, and the class of its element type. */
static int dataset_shape(hid_t dset, int *rank, hsize_t *dims, H5T_class_t *cls, char *msg,
                         size_t cap)
{
    hid_t space = -1, type = -1;
    int status = STATUS_OK;

    if ((space = H5Dget_space(dset)) < 0 || (*rank = H5Sget_simple_extent_ndims(space)) < 0) {
        status = fail_hdf5(msg, cap, "unable to get dataspace");
        goto done;
    }
    if (*rank > MAX_RANK) {
        status = fail_text(msg, cap, STATUS_MISMATCH, "dataset rank is too large");
        goto done;
    }
    if (H5Sget_simple_extent_dims(space, dims, NULL) < 0) {
        status = fail_hdf5(msg, cap, "unable to get dimensions");
        goto done;
    }
    if ((type = H5Dget_type(dset)) < 0 || (*cls = H5Tget_class(type)) == H5T_NO_CLASS) {
        status = fail_hdf5(msg, cap, "unable to get datatype");
        goto done;
    }
done:
    close_id(type, H5Tclose);
    close_id(space, H5Sclose);
    return status;
}

int twomem_h5_dims(int64_t fid, const char *path, int *rank, int64_t *dims, char *msg, size_t cap)
{
    hsize_t hdims[MAX_RANK];
    H5T_class_t cls;
    hid_t dset;
    int status;

    quiet();
    if ((dset = H5Dopen2(fid, path, H5P_DEFAULT)) < 0) return fail_hdf5(msg, cap, "unable to open dataset");
    status = dataset_shape(dset, rank, hdims, &cls, msg, cap);
    H5Dclose(dset);
    if (status == STATUS_OK)
        for (int i = 0; i < *rank; ++i) dims[i] = (int64_t)hdims[i];
    return status;
}

/* Reads only when the dataset has exactly the expected rank, dims and kind of number, so the
 * caller's buffer (allocated from twomem_h5_dims) can never be overrun. */
static int read_dataset(hid_t fid, const char *path, int rank, const int64_t *dims,
                        H5T_class_t want, hid_t mem_type, void *data, char *msg, size_t cap)
{
    hsize_t hdims[MAX_RANK];
    H5T_class_t cls;
    int frank;
    hid_t dset;
    int status;

    quiet();
    if ((dset = H5Dopen2(fid, path, H5P_DEFAULT)) < 0) return fail_hdf5(msg, cap, "unable to open dataset");
    status = dataset_shape(dset, &frank, hdims, &cls, msg, cap);
    if (status == STATUS_OK && frank != rank) {
        char text[128];
        snprintf(text, sizeof text, "dataset has rank %d, expected %d", frank, rank);
        status = fail_text(msg, cap, STATUS_MISMATCH, text);
    }
    for (int i = 0; status == STATUS_OK && i < rank; ++i)
        if (hdims[i] != (hsize_t)dims[i])
            status = fail_text(msg, cap, STATUS_MISMATCH, "dataset dimensions changed while reading");
    if (status == STATUS_OK && cls != want)
        status = fail_text(msg, cap, STATUS_MISMATCH,
                           want == H5T_FLOAT ? "dataset is not floating-point" : "dataset is not integer");
    if (status == STATUS_OK && H5Dread(dset, mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
        status = fail_hdf5(msg, cap, "unable to read dataset");
    H5Dclose(dset);
    return status;
}

int twomem_h5_read_double(int64_t fid, const char *path, int rank, const int64_t *dims, double *data,
                          char *msg, size_t cap)
{
    return read_dataset(fid, path, rank, dims, H5T_FLOAT, H5T_NATIVE_DOUBLE, data, msg, cap);
}

int twomem_h5_read_int(int64_t fid, const char *path, int rank, const int64_t *dims, int *data,
                       char *msg, size_t cap)
{
    return read_dataset(fid, path, rank, dims, H5T_INTEGER, H5T_NATIVE_INT, data, msg, cap);
}

/* ---- attributes ------------------------------------------------------------------------- */

/* The object that carries an attribute; a missing group is created (with its parents). */
static hid_t open_or_create_object(hid_t fid, const char *obj, char *msg, size_t cap)
{
    hid_t id, lcpl;

    if (strcmp(obj, "/") == 0 || path_exists(fid, obj)) {
        id = H5Oopen(fid, obj, H5P_DEFAULT);
        if (id < 0) fail_hdf5(msg, cap, "unable to open object");
        return id;
    }
    if ((lcpl = H5Pcreate(H5P_LINK_CREATE)) < 0 || H5Pset_create_intermediate_group(lcpl, 1) < 0) {
        fail_hdf5(msg, cap, "unable to set up link creation");
        close_id(lcpl, H5Pclose);
        return -1;
    }
    id = H5Gcreate2(fid, obj, lcpl, H5P_DEFAULT, H5P_DEFAULT);
    if (id < 0) fail_hdf5(msg, cap, "unable to create group");
    H5Pclose(lcpl);
    return id;
}

static int write_attribute(hid_t fid, const char *obj, const char *name, hid_t file_type,
                           hid_t mem_type, const void *value, char *msg, size_t cap)
{
    hid_t oid = -1, space = -1, attr = -1;
    int status = STATUS_OK;
    htri_t exists;

    quiet();
    if ((oid = open_or_create_object(fid, obj, msg, cap)) < 0) return STATUS_HDF5;
    if ((exists = H5Aexists(oid, name)) < 0 || (exists > 0 && H5Adelete(oid, name) < 0)) {
        status = fail_hdf5(msg, cap, "unable to replace attribute");
        goto done;
    }
    if ((space = H5Screate(H5S_SCALAR)) < 0) {
        status = fail_hdf5(msg, cap, "unable to create dataspace");
        goto done;
    }
    if ((attr = H5Acreate2(oid, name, file_type, space, H5P_DEFAULT, H5P_DEFAULT)) < 0) {
        status = fail_hdf5(msg, cap, "unable to create attribute");
        goto done;
    }
    if (H5Awrite(attr, mem_type, value) < 0) {
        status = fail_hdf5(msg, cap, "unable to write attribute");
        goto done;
    }
done:
    close_id(attr, H5Aclose);
    close_id(space, H5Sclose);
    H5Oclose(oid);
    return status;
}

/* Variable-length UTF-8: h5py returns it as a Python str (a fixed-length string would come
 * back as bytes), and its size is not bounded by the 64 KiB object-header limit. */
int twomem_h5_write_attr_string(int64_t fid, const char *obj, const char *name, const char *value,
                                int64_t len, char *msg, size_t cap)
{
    hid_t type;
    char *copy;
    int status;

    quiet();
    if ((type = H5Tcopy(H5T_C_S1)) < 0 || H5Tset_size(type, H5T_VARIABLE) < 0 ||
        H5Tset_cset(type, H5T_CSET_UTF8) < 0) {
        status = fail_hdf5(msg, cap, "unable to create string type");
        close_id(type, H5Tclose);
        return status;
    }
    copy = malloc((size_t)len + 1);
    if (!copy) {
        H5Tclose(type);
        return fail_text(msg, cap, STATUS_NOMEM, "out of memory");
    }
    memcpy(copy, value, (size_t)len);
    copy[len] = '\0';
    status = write_attribute(fid, obj, name, type, type, &copy, msg, cap);
    free(copy);
    H5Tclose(type);
    return status;
}

int twomem_h5_write_attr_double(int64_t fid, const char *obj, const char *name, double value,
                                char *msg, size_t cap)
{
    return write_attribute(fid, obj, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &value, msg, cap);
}

int twomem_h5_write_attr_int(int64_t fid, const char *obj, const char *name, int value, char *msg,
                             size_t cap)
{
    return write_attribute(fid, obj, name, H5T_STD_I32LE, H5T_NATIVE_INT, &value, msg, cap);
}

/* Opens a single-valued attribute of the expected class; returns its file type in *type. */
static hid_t open_scalar_attribute(hid_t fid, const char *obj, const char *name, H5T_class_t want,
                                   hid_t *type, char *msg, size_t cap)
{
    hid_t attr, space;
    hssize_t npoints;
    const char *what = want == H5T_STRING ? "attribute is not a string"
                       : want == H5T_FLOAT ? "attribute is not floating-point"
                                           : "attribute is not integer";

    *type = -1;
    if ((attr = H5Aopen_by_name(fid, obj, name, H5P_DEFAULT, H5P_DEFAULT)) < 0) {
        fail_hdf5(msg, cap, "unable to open attribute");
        return -1;
    }
    if ((space = H5Aget_space(attr)) < 0 || (npoints = H5Sget_simple_extent_npoints(space)) < 0 ||
        (*type = H5Aget_type(attr)) < 0) {
        fail_hdf5(msg, cap, "unable to inspect attribute");
    } else if (npoints != 1) {
        fail_text(msg, cap, STATUS_MISMATCH, "attribute is not a single value");
    } else if (H5Tget_class(*type) != want) {
        fail_text(msg, cap, STATUS_MISMATCH, what);
    } else {
        H5Sclose(space);
        return attr;
    }
    close_id(space, H5Sclose);
    close_id(*type, H5Tclose);
    *type = -1;
    H5Aclose(attr);
    return -1;
}

/* Reads a string attribute, variable or fixed length, into a malloc'ed NUL-terminated copy. */
static int read_string_attribute(hid_t fid, const char *obj, const char *name, char **out,
                                 char *msg, size_t cap)
{
    hid_t attr, ftype, mtype = -1;
    int status = STATUS_OK;

    *out = NULL;
    quiet();
    if ((attr = open_scalar_attribute(fid, obj, name, H5T_STRING, &ftype, msg, cap)) < 0) return STATUS_HDF5;
    if ((mtype = H5Tget_native_type(ftype, H5T_DIR_DEFAULT)) < 0) {
        status = fail_hdf5(msg, cap, "unable to get string type");
    } else if (H5Tis_variable_str(ftype) > 0) {
        char *text = NULL;
        if (H5Aread(attr, mtype, &text) < 0) {
            status = fail_hdf5(msg, cap, "unable to read attribute");
        } else {
            size_t n = text ? strlen(text) : 0;
            if ((*out = malloc(n + 1))) {
                memcpy(*out, text ? text : "", n + 1);
            } else {
                status = fail_text(msg, cap, STATUS_NOMEM, "out of memory");
            }
            H5free_memory(text);
        }
    } else {
        size_t size = H5Tget_size(ftype);
        if (!(*out = calloc(size + 1, 1))) {
            status = fail_text(msg, cap, STATUS_NOMEM, "out of memory");
        } else if (H5Aread(attr, mtype, *out) < 0) {
            status = fail_hdf5(msg, cap, "unable to read attribute");
        } else if (H5Tget_strpad(ftype) == H5T_STR_SPACEPAD) {
            for (size_t n = strlen(*out); n > 0 && (*out)[n - 1] == ' '; --n) (*out)[n - 1] = '\0';
        }
    }
    if (status != STATUS_OK) {
        free(*out);
        *out = NULL;
    }
    close_id(mtype, H5Tclose);
    H5Tclose(ftype);
    H5Aclose(attr);
    return status;
}

int twomem_h5_attr_string_len(int64_t fid, const char *obj, const char *name, int64_t *len, char *msg,
                              size_t cap)
{
    char *text;
    int status = read_string_attribute(fid, obj, name, &text, msg, cap);

    if (status == STATUS_OK) *len = (int64_t)strlen(text);
    free(text);
    return status;
}

/* Copies exactly len characters (the length twomem_h5_attr_string_len reported), no NUL. */
int twomem_h5_read_attr_string(int64_t fid, const char *obj, const char *name, char *value,
                               int64_t len, char *msg, size_t cap)
{
    char *text;
    int status = read_string_attribute(fid, obj, name, &text, msg, cap);

    if (status == STATUS_OK) {
        if ((int64_t)strlen(text) != len)
            status = fail_text(msg, cap, STATUS_MISMATCH, "attribute changed while reading");
        else
            memcpy(value, text, (size_t)len);
    }
    free(text);
    return status;
}

static int read_scalar_attribute(hid_t fid, const char *obj, const char *name, H5T_class_t want,
                                 hid_t mem_type, void *value, char *msg, size_t cap)
{
    hid_t attr, ftype;
    int status = STATUS_OK;

    quiet();
    if ((attr = open_scalar_attribute(fid, obj, name, want, &ftype, msg, cap)) < 0) return STATUS_HDF5;
    if (H5Aread(attr, mem_type, value) < 0) status = fail_hdf5(msg, cap, "unable to read attribute");
    H5Tclose(ftype);
    H5Aclose(attr);
    return status;
}

int twomem_h5_read_attr_double(int64_t fid, const char *obj, const char *name, double *value,
                               char *msg, size_t cap)
{
    return read_scalar_attribute(fid, obj, name, H5T_FLOAT, H5T_NATIVE_DOUBLE, value, msg, cap);
}

int twomem_h5_read_attr_int(int64_t fid, const char *obj, const char *name, int *value, char *msg,
                            size_t cap)
{
    return read_scalar_attribute(fid, obj, name, H5T_INTEGER, H5T_NATIVE_INT, value, msg, cap);
}
