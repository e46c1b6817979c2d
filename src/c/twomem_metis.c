/* Thin glue to METIS 5: partition the triangles of a mesh into nparts parts of nearly equal
 * size with few cut edges, through the dual graph (two triangles are neighbours when they share
 * an edge: ncommon = 2). Called from the Fortran module twomem_mesh_metis only. The seed is
 * fixed, so a mesh always gets the same partition. Returns METIS's status (METIS_OK = 1). */
#include <stdlib.h>
#include <metis.h>

int twomem_metis_partition(int nt, int nv, const int *triangles, int nparts, int *part)
{
    idx_t ne = nt, nn = nv, ncommon = 2, np = nparts, objval = 0;
    idx_t options[METIS_NOPTIONS];
    idx_t *eptr = malloc(sizeof(idx_t) * (size_t)(nt + 1));
    idx_t *eind = malloc(sizeof(idx_t) * (size_t)(3 * nt));
    idx_t *epart = malloc(sizeof(idx_t) * (size_t)nt);
    idx_t *npart = malloc(sizeof(idx_t) * (size_t)nv);
    int status;

    if (!eptr || !eind || !epart || !npart) {
        free(eptr);
        free(eind);
        free(epart);
        free(npart);
        return METIS_ERROR_MEMORY;
    }
    for (int t = 0; t <= nt; ++t) eptr[t] = 3 * t;
    /* the Fortran side numbers vertices from 1 */
    for (int k = 0; k < 3 * nt; ++k) eind[k] = triangles[k] - 1;
    METIS_SetDefaultOptions(options);
    options[METIS_OPTION_SEED] = 20261124;
    if (nparts == 1) {
        for (int t = 0; t < nt; ++t) epart[t] = 0;
        status = METIS_OK;
    } else {
        status = METIS_PartMeshDual(&ne, &nn, eptr, eind, NULL, NULL, &ncommon, &np, NULL, options, &objval, epart,
                                    npart);
    }
    if (status == METIS_OK)
        for (int t = 0; t < nt; ++t) part[t] = (int)epart[t];
    free(eptr);
    free(eind);
    free(epart);
    free(npart);
    return status;
}
