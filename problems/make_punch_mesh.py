"""Write punch_2d.msh with gmsh: a 20 x 10 block, a 6 mm contact segment in
the middle of the bottom, named physical groups, refined toward the contact.

    pip install gmsh && python problems/make_punch_mesh.py

gmsh keeps the geometry points in the file even where no triangle uses them;
elastoplast drops such nodes when it reads the mesh.
"""

from pathlib import Path

import gmsh


def main(path: Path = Path(__file__).with_name("punch_2d.msh"), h_far: float = 1.0, h_contact: float = 0.15) -> None:
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.model.add("punch_2d")
    geo = gmsh.model.geo
    xy = [(-10, 0, h_far), (-3, 0, h_contact), (3, 0, h_contact), (10, 0, h_far), (10, 10, h_far), (-10, 10, h_far)]
    pts = [geo.addPoint(x, y, 0.0, h) for x, y, h in xy]
    lines = [geo.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    loop = geo.addCurveLoop(lines)
    surface = geo.addPlaneSurface([loop])
    geo.synchronize()
    groups = {"free_bottom": [lines[0], lines[2]], "contact": [lines[1]], "right": [lines[3]],
              "top": [lines[4]], "left": [lines[5]]}
    for name, tags in groups.items():
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, tags), name)
    gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), "body")
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.model.mesh.generate(2)
    gmsh.write(str(path))
    gmsh.finalize()


if __name__ == "__main__":
    main()
