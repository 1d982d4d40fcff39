"""Write ``block_boss.step``: a B-rep solid in millimetres, the STEP part the suite reads.

A block 80 x 60 x 20 mm (corner at (-40, -30, 0)) with a round boss of diameter 20 mm and
height 15 mm at (15, 5) on its top face: six planar faces (the top one with the boss's circle
as its inner bound), the boss's cylindrical face (closed by a seam edge) and its top, as CAD
software exports an AP214 part (``ADVANCED_BREP_SHAPE_REPRESENTATION`` in a product, units in
the file: ``SI_UNIT(.MILLI.,.METRE.)``).

    python tests/data/step/make_step.py      # rewrites tests/data/step/block_boss.step
"""

from __future__ import annotations

from pathlib import Path

# the block and the boss [mm]
X0, X1, Y0, Y1, Z0, Z1 = -40.0, 40.0, -30.0, 30.0, 0.0, 20.0
BX, BY, BR, BZ = 15.0, 5.0, 10.0, 35.0


class Step:
    """Entities numbered in the order written."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def add(self, text: str) -> str:
        self.lines.append(f"#{len(self.lines) + 1}={text};")
        return f"#{len(self.lines)}"

    def point(self, p) -> str:
        return self.add("CARTESIAN_POINT('',({:.6f},{:.6f},{:.6f}))".format(*p))

    def direction(self, d) -> str:
        return self.add("DIRECTION('',({:.6f},{:.6f},{:.6f}))".format(*d))

    def placement(self, origin, axis, ref) -> str:
        return self.add(f"AXIS2_PLACEMENT_3D('',{self.point(origin)},{self.direction(axis)},{self.direction(ref)})")

    def vertex(self, p) -> str:
        return self.add(f"VERTEX_POINT('',{self.point(p)})")

    def line_edge(self, v0: str, v1: str, p0, p1) -> str:
        d = [b - a for a, b in zip(p0, p1, strict=True)]
        n = sum(x * x for x in d) ** 0.5
        vec = self.add(f"VECTOR('',{self.direction([x / n for x in d])},{n:.6f})")
        line = self.add(f"LINE('',{self.point(p0)},{vec})")
        return self.add(f"EDGE_CURVE('',{v0},{v1},{line},.T.)")

    def circle_edge(self, v: str, centre, radius: float) -> str:
        circle = self.add(f"CIRCLE('',{self.placement(centre, (0, 0, 1), (1, 0, 0))},{radius:.6f})")
        return self.add(f"EDGE_CURVE('',{v},{v},{circle},.T.)")

    def loop(self, edges: list[tuple[str, bool]]) -> str:
        oriented = [self.add(f"ORIENTED_EDGE('',*,*,{e},{'.T.' if s else '.F.'})") for e, s in edges]
        return self.add(f"EDGE_LOOP('',({','.join(oriented)}))")

    def face(self, surface: str, outer: str, inner: list[str] = ()) -> str:
        bounds = [self.add(f"FACE_OUTER_BOUND('',{outer},.T.)")]
        bounds += [self.add(f"FACE_BOUND('',{b},.T.)") for b in inner]
        return self.add(f"ADVANCED_FACE('',({','.join(bounds)}),{surface},.T.)")

    def plane(self, origin, normal, ref) -> str:
        return self.add(f"PLANE('',{self.placement(origin, normal, ref)})")


def block_boss() -> str:
    s = Step()
    ctx = s.add("APPLICATION_CONTEXT('automotive design')")
    s.add(f"APPLICATION_PROTOCOL_DEFINITION('international standard','automotive_design',2000,{ctx})")
    product_context = s.add(f"PRODUCT_CONTEXT('',{ctx},'mechanical')")
    product = s.add(f"PRODUCT('block_boss','block_boss','',({product_context}))")
    formation = s.add(f"PRODUCT_DEFINITION_FORMATION('','',{product})")
    pdc = s.add(f"PRODUCT_DEFINITION_CONTEXT('part definition',{ctx},'design')")
    definition = s.add(f"PRODUCT_DEFINITION('design','',{formation},{pdc})")
    pds = s.add(f"PRODUCT_DEFINITION_SHAPE('','',{definition})")

    corners = {(i, j, k): (X1 if i else X0, Y1 if j else Y0, Z1 if k else Z0)
               for i in (0, 1) for j in (0, 1) for k in (0, 1)}
    v = {key: s.vertex(p) for key, p in corners.items()}
    edges: dict[tuple, str] = {}

    def edge(a, b) -> tuple[str, bool]:
        """The line edge between corners a and b, and whether it runs a -> b."""
        if (b, a) in edges:
            return edges[(b, a)], False
        if (a, b) not in edges:
            edges[(a, b)] = s.line_edge(v[a], v[b], corners[a], corners[b])
        return edges[(a, b)], True

    def quad(a, b, c, d) -> str:
        """A loop through four corners, counter-clockwise seen from outside."""
        return s.loop([edge(a, b), edge(b, c), edge(c, d), edge(d, a)])

    faces = [
        s.face(s.plane(corners[0, 0, 0], (0, 0, -1), (1, 0, 0)), quad((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0))),
        s.face(s.plane(corners[0, 0, 0], (0, -1, 0), (1, 0, 0)), quad((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1))),
        s.face(s.plane(corners[1, 0, 0], (1, 0, 0), (0, 1, 0)), quad((1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1))),
        s.face(s.plane(corners[1, 1, 0], (0, 1, 0), (-1, 0, 0)), quad((1, 1, 0), (0, 1, 0), (0, 1, 1), (1, 1, 1))),
        s.face(s.plane(corners[0, 1, 0], (-1, 0, 0), (0, -1, 0)), quad((0, 1, 0), (0, 0, 0), (0, 0, 1), (0, 1, 1))),
    ]
    # the boss: its circles on the top face and at its top, the seam at +x, the cylinder
    seam0, seam1 = (BX + BR, BY, Z1), (BX + BR, BY, BZ)
    vb0, vb1 = s.vertex(seam0), s.vertex(seam1)
    c_low = s.circle_edge(vb0, (BX, BY, Z1), BR)
    c_top = s.circle_edge(vb1, (BX, BY, BZ), BR)
    seam = s.line_edge(vb0, vb1, seam0, seam1)
    top = s.plane(corners[0, 0, 1], (0, 0, 1), (1, 0, 0))
    outer = quad((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))
    faces.append(s.face(top, outer, [s.loop([(c_low, False)])]))  # the hole in the top face runs clockwise
    cylinder = s.add(f"CYLINDRICAL_SURFACE('',{s.placement((BX, BY, Z1), (0, 0, 1), (1, 0, 0))},{BR:.6f})")
    faces.append(s.face(cylinder, s.loop([(c_low, True), (seam, True), (c_top, False), (seam, False)])))
    faces.append(s.face(s.plane((BX, BY, BZ), (0, 0, 1), (1, 0, 0)), s.loop([(c_top, True)])))

    shell = s.add("CLOSED_SHELL('',(" + ",".join(faces) + "))")
    solid = s.add(f"MANIFOLD_SOLID_BREP('block_boss',{shell})")
    mm = s.add("( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) )")
    rad = s.add("( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) )")
    sr = s.add("( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() )")
    unc = s.add(f"UNCERTAINTY_MEASURE_WITH_UNIT(LENGTH_MEASURE(1.E-07),{mm},'distance_accuracy_value','confusion "
                "accuracy')")
    context = s.add(f"( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT(({unc})) "
                    f"GLOBAL_UNIT_ASSIGNED_CONTEXT(({mm},{rad},{sr})) REPRESENTATION_CONTEXT('Context #1','3D') )")
    origin = s.placement((0, 0, 0), (0, 0, 1), (1, 0, 0))
    rep = s.add(f"ADVANCED_BREP_SHAPE_REPRESENTATION('',({solid},{origin}),{context})")
    s.add(f"SHAPE_DEFINITION_REPRESENTATION({pds},{rep})")
    head = ["ISO-10303-21;", "HEADER;", "FILE_DESCRIPTION(('block with a round boss'),'2;1');",
            "FILE_NAME('block_boss.step','2026-11-27T00:00:00',(''),(''),'','','');",
            "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));", "ENDSEC;", "DATA;"]
    return "\n".join([*head, *s.lines, "ENDSEC;", "END-ISO-10303-21;"]) + "\n"


if __name__ == "__main__":
    (Path(__file__).parent / "block_boss.step").write_text(block_boss())
