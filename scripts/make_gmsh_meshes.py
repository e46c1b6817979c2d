#!/usr/bin/env python3
"""Regenerate the Gmsh meshes of twomem with the Gmsh Python API.

The meshes in input/meshes/ are the domains of the example cases; the small ones in
tests/data/meshes/ are the unit-test inputs of the Gmsh reader (test_gmsh.f90 checks their
vertex and triangle counts, so regenerate them only together with that test). Meshing runs on
one thread with fixed sizes and the default algorithms, so a given Gmsh version writes the same
bytes every time.

    python3 -m venv /tmp/gmshvenv && /tmp/gmshvenv/bin/pip install gmsh
    /tmp/gmshvenv/bin/python scripts/make_gmsh_meshes.py          # all meshes
    /tmp/gmshvenv/bin/python scripts/make_gmsh_meshes.py --list   # what would be written
"""

import argparse
import pathlib
import sys

import gmsh

ROOT = pathlib.Path(__file__).resolve().parent.parent


def polygon_geo(corners, size, groups):
    """A plane polygon in the built-in kernel, whose vertices keep exactly the given coordinates
    (the OpenCASCADE kernel would leave round-off in boundary nodes)."""
    geo = gmsh.model.geo
    points = [geo.addPoint(x, y, 0.0, size) for x, y in corners]
    lines = [geo.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))]
    loop = geo.addCurveLoop(lines)
    surface = geo.addPlaneSurface([loop])
    geo.synchronize()
    if groups:
        gmsh.model.addPhysicalGroup(2, [surface], 1, name="domain")
        gmsh.model.addPhysicalGroup(1, lines, 2, name="boundary")


def disk_occ(size):
    """The unit disk (OpenCASCADE: a disk has no centre point, which would be a stray node)."""
    surface = gmsh.model.occ.addDisk(0.0, 0.0, 0.0, 1.0, 1.0)
    gmsh.model.occ.synchronize()
    gmsh.model.mesh.setSize(gmsh.model.getEntities(0), size)
    boundary = [tag for _, tag in gmsh.model.getBoundary([(2, surface)], oriented=False)]
    gmsh.model.addPhysicalGroup(2, [surface], 1, name="domain")
    gmsh.model.addPhysicalGroup(1, boundary, 2, name="boundary")


def square_hole_occ(size, hole_size):
    """(-1,1)^2 minus the disk of radius 0.3 at the origin: two boundary components."""
    occ = gmsh.model.occ
    square = occ.addRectangle(-1.0, -1.0, 0.0, 2.0, 2.0)
    hole = occ.addDisk(0.0, 0.0, 0.0, 0.3, 0.3)
    cut, _ = occ.cut([(2, square)], [(2, hole)])
    occ.synchronize()
    surface = cut[0][1]
    gmsh.model.mesh.setSize(gmsh.model.getEntities(0), size)
    curves = [tag for _, tag in gmsh.model.getBoundary(cut, oriented=False)]
    outer, inner = [], []
    for tag in curves:
        xmin, ymin, _, xmax, ymax, _ = gmsh.model.getBoundingBox(1, tag)
        (inner if max(abs(xmin), abs(xmax), abs(ymin), abs(ymax)) < 0.5 else outer).append(tag)
    for tag in inner:
        gmsh.model.mesh.setSize(gmsh.model.getBoundary([(1, tag)], oriented=False), hole_size)
    gmsh.model.addPhysicalGroup(2, [surface], 1, name="domain")
    gmsh.model.addPhysicalGroup(1, outer, 2, name="outer")
    gmsh.model.addPhysicalGroup(1, inner, 3, name="hole")


L_CORNERS = [(-1, -1), (0, -1), (0, 0), (1, 0), (1, 1), (-1, 1)]
SQUARE_CORNERS = [(-1, -1), (1, -1), (1, 1), (-1, 1)]

# file, MSH version, geometry builder
MESHES = [
    ("input/meshes/lshape.msh", 4.1, lambda: polygon_geo(L_CORNERS, 0.06, groups=True)),
    ("input/meshes/disk_gmsh.msh", 2.2, lambda: disk_occ(0.06)),
    ("input/meshes/square_hole.msh", 4.1, lambda: square_hole_occ(0.065, 0.04)),
    ("tests/data/meshes/square_msh22.msh", 2.2, lambda: polygon_geo(SQUARE_CORNERS, 0.5, False)),
    ("tests/data/meshes/square_msh22_groups.msh", 2.2,
     lambda: polygon_geo(SQUARE_CORNERS, 0.5, True)),
    ("tests/data/meshes/square_msh41.msh", 4.1, lambda: polygon_geo(SQUARE_CORNERS, 0.5, False)),
    ("tests/data/meshes/square_msh41_groups.msh", 4.1,
     lambda: polygon_geo(SQUARE_CORNERS, 0.5, True)),
    ("tests/data/meshes/lshape_msh41.msh", 4.1, lambda: polygon_geo(L_CORNERS, 0.15, True)),
]


def write_mesh(path, version, build):
    gmsh.clear()
    gmsh.model.add(path.stem)
    build()
    gmsh.model.mesh.generate(2)
    gmsh.option.setNumber("Mesh.MshFileVersion", version)
    gmsh.option.setNumber("Mesh.Binary", 0)
    # without physical groups every element is written, with them only the grouped ones
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.write(str(path))
    _, triangles, _ = gmsh.model.mesh.getElements(2)
    n_nodes = len(gmsh.model.mesh.getNodes()[0])
    n_triangles = sum(len(t) for t in triangles)
    print(f"{path.relative_to(ROOT)}: MSH {version}, {n_nodes} nodes, {n_triangles} triangles")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--list", action="store_true", help="only list the files")
    args = parser.parse_args()
    if args.list:
        for name, version, _ in MESHES:
            print(f"{name} (MSH {version})")
        return 0
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay, Gmsh's default for 2D
        print(f"gmsh {gmsh.__version__}")
        for name, version, build in MESHES:
            write_mesh(ROOT / name, version, build)
    finally:
        gmsh.finalize()
    return 0


if __name__ == "__main__":
    sys.exit(main())
