"""NURBS models in CAD files: IGES (entity 128) and Rhino .3dm, read and written with their parts.

IGES is read and written here (numpy only): a fixed-column format of 80-character records whose
rational B-spline surfaces (entity 128) carry everything a part needs. pyiges 0.3.4 was tried
and not used: it reads entity 128's parameter range from the wrong fields (``v1`` comes out as
the entity type, 128) and drops entities it cannot parse with a printed warning, where a model
must be refused with its file and entity named. :func:`read_parts` (solids) refuses trimmed
surfaces (entity 144) and B-rep solids (entity 186) with a message: SEM needs whole NURBS parts;
:func:`read_shell_parts` (shells) reads trimmed surfaces with their trim loops
(:mod:`bhem_hpc.io.iges_trim`), and :func:`write_parts` writes them back so. Rhino files go through
McNeel's ``rhino3dm`` (OpenNURBS): NURBS surfaces, B-rep faces and surfaces that convert to NURBS
are read; trimmed faces are refused for solids and read with their loops for shells. Written files
hold one NURBS surface per part, in order, with the parts' names (the ``.3dm`` object names; IGES
entity labels).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bhem_hpc.geometry.nurbs import NurbsSurface
from bhem_hpc.geometry.surface import SurfaceError

IGES_SUFFIXES = (".igs", ".iges")
RHINO_SUFFIXES = (".3dm",)
#: Entities that bound or trim surfaces: their models need trimming, which SEM parts do not have.
TRIMMING_ENTITIES = {143: "bounded surface", 144: "trimmed surface", 186: "manifold solid B-rep", 510: "face"}


def read_parts(path: str | Path) -> list[NurbsSurface]:
    """The NURBS parts of an IGES or .3dm file, in file order.

    Raises:
        SurfaceError: a missing file, an unknown suffix, a file without surfaces, trimmed
            surfaces, or bad surface data (naming the file and the entity or object).
    """
    path = Path(path)
    if not path.is_file():
        raise SurfaceError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in IGES_SUFFIXES:
        parts = _read_iges(path)
    elif suffix in RHINO_SUFFIXES:
        parts = _read_rhino(path)
    else:
        raise SurfaceError(f"{path}: a NURBS model must be an IGES ({', '.join(IGES_SUFFIXES)}) or Rhino (.3dm) file")
    if not parts:
        raise SurfaceError(f"{path}: the file holds no NURBS surface")
    return parts


def write_parts(path: str | Path, parts: Sequence[NurbsSurface | ShellPart]) -> None:
    """Write ``parts`` as an IGES or .3dm file (by the suffix), one NURBS surface per part; IGES
    keeps the trims of trimmed :class:`ShellPart` s (trimmed surfaces, entity 144)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in RHINO_SUFFIXES and any(isinstance(p, ShellPart) and p.loops is not None for p in parts):
        raise SurfaceError(f"{path}: trimmed parts are written as IGES (.igs), not .3dm")
    parts = [p.surface if isinstance(p, ShellPart) and suffix not in IGES_SUFFIXES else p for p in parts]
    if suffix in IGES_SUFFIXES:
        path.write_text(_iges_text(parts, path.name))
    elif suffix in RHINO_SUFFIXES:
        _write_rhino(path, parts)
    else:
        raise SurfaceError(f"{path}: a NURBS model must be written as IGES ({', '.join(IGES_SUFFIXES)}) or .3dm")


# ---- IGES ------------------------------------------------------------------------------------


def _iges_number(text: str) -> float:
    return float(text.strip().replace("D", "E").replace("d", "e"))


def iges_numbers(fields: list[str]) -> np.ndarray:
    """An entity's parameters after its type (``fields[0]``) as numbers, empty fields left out."""
    return np.array([_iges_number(f) for f in fields[1:] if f.strip()])


def _iges_sections(path: Path) -> dict[str, list[str]]:
    sections: dict[str, list[str]] = {"S": [], "G": [], "D": [], "P": [], "T": []}
    for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        if not line.strip():
            continue
        code = line[72:73]
        if code not in sections:
            raise SurfaceError(
                f"{path}: line {number} is not an IGES record (column 73 is {code!r}, not S, G, D, P or T)"
            )
        sections[code].append(line[:80].ljust(80))
    if not sections["D"]:
        raise SurfaceError(f"{path}: not an IGES file (no directory entries)")
    return sections


def _delimiters(global_text: str) -> tuple[str, str]:
    """The parameter and record delimiters: the global section's first two fields (default , ;)."""
    parameter, record = ",", ";"
    if global_text.startswith("1H"):
        parameter = global_text[2]
        rest = global_text[3:].lstrip(parameter)
        if rest.startswith("1H"):
            record = rest[2]
    return parameter, record


def _iges_entities(path: Path):
    """``{directory sequence number: (type, transform pointer, status, parameters, entity label)}``."""
    sections = _iges_sections(path)
    parameter, record = _delimiters("".join(line[:72] for line in sections["G"]).strip())
    data = sections["P"]
    entities = {}
    directory = sections["D"]
    for first in range(0, len(directory) - 1, 2):
        top, bottom = directory[first], directory[first + 1]
        try:
            kind, pointer, transform = int(top[0:8]), int(top[8:16]), int(top[48:56] or 0)
            status, count, label = top[64:72].replace(" ", "0"), int(bottom[24:32]), bottom[56:64].strip()
        except ValueError as error:
            raise SurfaceError(f"{path}: directory entry at D{first + 1} is malformed ({error})") from None
        text = "".join(line[:64] for line in data[pointer - 1 : pointer - 1 + count])
        text = text.split(record)[0]
        entities[first + 1] = (kind, transform, status, [field for field in text.split(parameter)], label)
    return entities


def _transform(entities, pointer: int, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``(3, 3)`` and translation ``(3,)`` of transformation entity 124 at ``pointer``
    (composed with the transformations it points to)."""
    rotation, translation = np.eye(3), np.zeros(3)
    for _ in range(len(entities)):  # bounded: a chain visits each entity at most once
        if not pointer:
            break
        kind, parent, _, fields, _label = entities.get(pointer, (None, 0, "", [], ""))
        if kind != 124:
            raise SurfaceError(f"{path}: D{pointer} is not a transformation matrix (entity 124)")
        matrix = np.array([_iges_number(f) for f in fields[1:13]]).reshape(3, 4)
        rotation, translation = matrix[:, :3] @ rotation, matrix[:, :3] @ translation + matrix[:, 3]
        pointer = parent
    return rotation, translation


def _iges_surface(fields: list[str], label: str, path: Path) -> NurbsSurface:
    try:
        values = iges_numbers(fields)
        k1, k2, m1, m2 = (int(v) for v in values[:4])
        at = 9
        knots_u = values[at : at + k1 + m1 + 2]
        at += k1 + m1 + 2
        knots_v = values[at : at + k2 + m2 + 2]
        at += k2 + m2 + 2
        count = (k1 + 1) * (k2 + 1)
        weights = values[at : at + count]
        at += count
        control = values[at : at + 3 * count]
        at += 3 * count
        u0, u1, v0, v1 = values[at : at + 4]
    except (ValueError, IndexError) as error:
        raise SurfaceError(f"{path}: {label}: entity 128 parameters are malformed ({error})") from None
    if len(control) != 3 * count or len(values) < at + 4:
        raise SurfaceError(f"{path}: {label}: entity 128 has fewer parameters than its counts need")
    # IGES orders control points with the first index fastest: W(0,0), W(1,0), ..., W(K1,0), W(0,1), ...
    control = control.reshape(k2 + 1, k1 + 1, 3).transpose(1, 0, 2)
    weights = weights.reshape(k2 + 1, k1 + 1).T
    surface = NurbsSurface((m1, m2), knots_u, knots_v, control, weights, name=f"{path.name} {label}")
    (a, b), (c, d) = surface.u.domain, surface.v.domain
    if not np.allclose([u0, u1, v0, v1], [a, b, c, d], rtol=0, atol=1e-9 * max(1.0, abs(b - a), abs(d - c))):
        raise SurfaceError(
            f"{path}: {label}: its parameter range [{u0}, {u1}] x [{v0}, {v1}] is part of the knots' "
            f"[{a}, {b}] x [{c}, {d}]; export the surface untrimmed"
        )
    return surface


def _refuse_trimming(entities, path: Path, allowed: tuple[int, ...], whom: str) -> None:
    for pointer, (kind, *_rest) in entities.items():
        if kind in TRIMMING_ENTITIES and kind not in allowed:
            raise SurfaceError(
                f"{path}: D{pointer} is a {TRIMMING_ENTITIES[kind]} (entity {kind}); {whom}: untrim or split the "
                "model in the modeller, or export its surfaces untrimmed"
            )


def _iges_parts(entities, path: Path) -> list[tuple[int, NurbsSurface]]:
    """Every rational B-spline surface (128) of the file: its directory pointer and the part."""
    parts = []
    for pointer, (kind, transform, _status, fields, label) in entities.items():
        if kind != 128:
            continue
        surface = _iges_surface(fields, f"surface D{pointer}", path)
        if label:  # the part's entity label (8 characters at most), with its entry: unique
            surface = surface.with_name(f"{label} (D{pointer})")
        rotation, translation = _transform(entities, transform, path)
        parts.append((pointer, surface.with_control(surface.control @ rotation.T + translation)))
    return parts


def _read_iges(path: Path) -> list[NurbsSurface]:
    entities = _iges_entities(path)
    _refuse_trimming(entities, path, (), "SEM parts are whole NURBS surfaces")
    return [part for _, part in _iges_parts(entities, path)]


@dataclass(frozen=True)
class ShellPart:
    """A part of a surface model as a shell takes it: a NURBS surface and its trim.

    Attributes:
        surface: the part's surface (whole).
        loops: closed polygons ``(n_k, 2)`` in its parameters bounding what is kept (the first
            point repeated at the end), or None: all of it.
    """

    surface: NurbsSurface
    loops: tuple[np.ndarray, ...] | None = None


def read_shell_parts(path: str | Path) -> list[ShellPart]:
    """The parts of an IGES or .3dm file as shells take them: IGES trimmed surfaces (144) with their
    trim loops (:mod:`bhem_hpc.io.iges_trim`), trimmed B-rep faces of .3dm files with loops from
    their edges (:func:`_face_loops`), other surfaces whole.

    Raises:
        SurfaceError: as :func:`read_parts`; also a surface trimmed twice, or trim curves without
            parameter-space curves (naming the file and the entity).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (*IGES_SUFFIXES, *RHINO_SUFFIXES) or not path.is_file():
        return [ShellPart(part) for part in read_parts(path)]  # which refuses the file, naming why
    parts = _read_rhino(path, trimmed=True) if suffix in RHINO_SUFFIXES else _read_iges_shells(path)
    if not parts:
        raise SurfaceError(f"{path}: the file holds no NURBS surface")
    return parts


def _read_iges_shells(path: Path) -> list[ShellPart]:
    """:func:`read_shell_parts` of an IGES file."""
    from bhem_hpc.io.iges_trim import trimmed_surfaces

    entities = _iges_entities(path)
    _refuse_trimming(entities, path, (144,), "a shell takes whole or trimmed surfaces (entity 128, 144)")
    trims: dict[int, tuple] = {}
    for pointer, (surface, outer, holes) in trimmed_surfaces(entities, path).items():
        if surface in trims:
            raise SurfaceError(f"{path}: surface D{surface} is trimmed twice (D{trims[surface][0]} and D{pointer})")
        trims[surface] = (pointer, outer, holes)
    parts = []
    for pointer, surface in _iges_parts(entities, path):
        _, outer, holes = trims.get(pointer, (0, None, []))
        if outer is None and holes:  # holes in the whole surface: its boundary is the outer loop
            (a, b), (c, d) = surface.u.domain, surface.v.domain
            outer = np.array([(a, c), (b, c), (b, d), (a, d), (a, c)])
        loops = None if outer is None else (outer, *holes)
        parts.append(ShellPart(surface, loops))
    return parts


def _hollerith(text: str) -> str:
    return f"{len(text)}H{text}"


def _records(fields: Sequence[str], width: int, delimiter: str = ",", end: str = ";") -> list[str]:
    """Fields joined by the delimiter, ended by the record delimiter, broken into lines of ``width``
    without splitting a field."""
    lines, current = [], ""
    for index, field in enumerate(fields):
        token = field + (end if index == len(fields) - 1 else delimiter)
        if len(current) + len(token) > width:
            lines.append(current)
            current = ""
        current += token
    return [*lines, current]


def _surface_fields(part: NurbsSurface) -> list[str]:
    """Entity 128's parameters of ``part``."""
    (n, m), (p, q) = part.control.shape[:2], part.degrees
    polynomial = int(np.all(part.weights == part.weights.flat[0]))
    fields = ["128", str(n - 1), str(m - 1), str(p), str(q), "0", "0", str(polynomial), "0", "0"]
    fields += [repr(float(k)) for k in part.u.knots] + [repr(float(k)) for k in part.v.knots]
    fields += [repr(float(w)) for w in part.weights.T.ravel()]
    fields += [repr(float(c)) for c in part.control.transpose(1, 0, 2).reshape(-1)]
    return fields + [repr(float(x)) for x in (*part.u.domain, *part.v.domain)]


def _polyline_fields(loop: np.ndarray) -> list[str]:
    """Entity 126's parameters of a closed polygon in a surface's parameters: a degree-1 B-spline
    curve through its points (z = 0), parametrized by point index."""
    count = len(loop)
    knots = np.concatenate([[0.0], np.arange(count, dtype=float), [count - 1.0]])
    fields = ["126", str(count - 1), "1", "1", "1", "1", "0"]
    fields += [repr(float(k)) for k in knots] + ["1.0"] * count
    fields += [repr(float(c)) for point in loop for c in (point[0], point[1], 0.0)]
    return fields + ["0.0", repr(float(count - 1)), "0.0", "0.0", "1.0"]


def _iges_text(parts: Sequence[NurbsSurface | ShellPart], file_name: str) -> str:
    """An IGES file of ``parts``: one rational B-spline surface (128) per part and, for a trimmed
    :class:`ShellPart`, its loops as curves on the surface (126 in its parameters, 142) and the
    trimmed surface (144) of them."""
    entities: list[tuple[list[str], str]] = []  # (fields, label); entity k is directory entry 2 k + 1
    for index, item in enumerate(parts):
        part = item.surface if isinstance(item, ShellPart) else item
        label = re.sub(r"[^A-Za-z0-9]", "", part.name)[:8] or f"PART{index}"
        entities.append((_surface_fields(part), label))
        surface = 2 * len(entities) - 1
        loops = item.loops if isinstance(item, ShellPart) else None
        if loops is None:
            continue
        curves = []
        for loop in loops:
            entities.append((_polyline_fields(np.asarray(loop, dtype=float)), "TRIMPC"))
            entities.append((["142", "1", str(surface), str(2 * len(entities) - 1), "0", "1"], "TRIMCOS"))
            curves.append(str(2 * len(entities) - 1))
        entities.append((["144", str(surface), "1", str(len(curves) - 1), *curves], label))
    return _iges_document(entities, file_name)


def _iges_document(entities: Sequence[tuple[list[str], str]], file_name: str) -> str:
    start = ["NURBS model written by bhem-hpc: one rational B-spline surface per part"]
    global_fields = [
        _hollerith(","), _hollerith(";"), _hollerith("bhem-hpc"), _hollerith(file_name), _hollerith("bhem-hpc"),
        _hollerith("bhem-hpc"), "32", "308", "15", "308", "15", _hollerith(file_name), "1.0", "6", _hollerith("M"),
        "1", "1.0", _hollerith("20000101.000000"), "1.0E-9", "1.0E3", "", "", "11", "0",
    ]  # fmt: skip
    directory, parameter = [], []
    for index, (fields, label) in enumerate(entities):
        kind = int(fields[0])
        lines = _records(fields, 64)
        sequence = 2 * index + 1
        first_line = len(parameter) + 1
        parameter += [f"{line:<64}{sequence:>8}" for line in lines]
        directory.append(f"{kind:>8}{first_line:>8}{0:>8}{0:>8}{0:>8}{0:>8}{0:>8}{0:>8}{'00000000':>8}")
        directory.append(f"{kind:>8}{0:>8}{0:>8}{len(lines):>8}{0:>8}{'':>8}{'':>8}{label:>8}{index:>8}")
    out = []
    for code, lines in (("S", start), ("G", _records(global_fields, 72)), ("D", directory), ("P", parameter)):
        out += [f"{line:<72}{code}{number:>7}" for number, line in enumerate(lines, start=1)]
    counts = f"S{1:>7}G{len(_records(global_fields, 72)):>7}D{len(directory):>7}P{len(parameter):>7}"
    out.append(f"{counts:<72}T{1:>7}")
    return "\n".join(out) + "\n"


# ---- Rhino .3dm --------------------------------------------------------------------------------


def _xyzw(point) -> tuple[float, float, float, float]:
    return point.X, point.Y, point.Z, point.W


def _from_rhino(surface, name: str, reversed_u: bool = False) -> NurbsSurface:
    nurbs = surface.ToNurbsSurface()
    if nurbs is None:
        raise SurfaceError(f"{name}: the surface has no NURBS form")
    points = nurbs.Points
    count_u, count_v = points.CountU, points.CountV
    homogeneous = np.array([[_xyzw(points[i, j]) for j in range(count_v)] for i in range(count_u)], dtype=float)
    if nurbs.IsRational:  # OpenNURBS keeps rational control points homogeneous: (w x, w y, w z, w)
        homogeneous[..., :3] /= homogeneous[..., 3:]
    else:
        homogeneous[..., 3] = 1.0
    # OpenNURBS knot vectors leave out the superfluous first and last knots of the textbook form
    knots_u = np.array(nurbs.KnotsU.ToList(), dtype=float)
    knots_v = np.array(nurbs.KnotsV.ToList(), dtype=float)
    knots_u, knots_v = np.r_[knots_u[0], knots_u, knots_u[-1]], np.r_[knots_v[0], knots_v, knots_v[-1]]
    control, weights = homogeneous[..., :3], homogeneous[..., 3]
    if reversed_u:  # the face's normal is the surface's reversed: turn u round
        control, weights = control[::-1], weights[::-1]
        knots_u = knots_u[0] + knots_u[-1] - knots_u[::-1]
    return NurbsSurface((nurbs.OrderU - 1, nurbs.OrderV - 1), knots_u, knots_v, control, weights, name=name)


def _read_rhino(path: Path, trimmed: bool = False) -> list:
    """The parts of a .3dm file: NURBS surfaces; with ``trimmed``, :class:`ShellPart` s whose trimmed
    B-rep faces carry loops (:func:`_face_loops`), else a trimmed face is refused."""
    import rhino3dm

    model = rhino3dm.File3dm.Read(str(path))
    if model is None:
        raise SurfaceError(f"{path}: not a readable Rhino .3dm file")
    parts = []
    for index, item in enumerate(model.Objects):
        geometry = item.Geometry
        name = f"{path.name} object {index}" + (f" ({item.Attributes.Name})" if item.Attributes.Name else "")
        if isinstance(geometry, rhino3dm.Brep):
            for k, face in enumerate(geometry.Faces):
                surface = _from_rhino(face.UnderlyingSurface(), f"{name} face {k}", face.OrientationIsReversed)
                # a face alone is "a surface" when it is its whole underlying surface: untrimmed
                whole = face.DuplicateFace(False).IsSurface
                if not whole and not trimmed:
                    raise SurfaceError(
                        f"{path}: {name} face {k} is trimmed; SEM parts are whole NURBS surfaces: untrim or split "
                        "it in the modeller"
                    )
                if trimmed:
                    surface = ShellPart(surface, None if whole else _face_loops(geometry, face, surface))
                parts.append(surface)
        elif isinstance(geometry, rhino3dm.Surface):
            surface = _from_rhino(geometry, name)
            parts.append(ShellPart(surface) if trimmed else surface)
    return parts


#: Points sampled per trim of a .3dm face (along its 3D edge, which rhino3dm gives; it does not
#: give the trims' curves in the surface's parameters).
RHINO_TRIM_SAMPLES = 64
#: How far [relative to the part's size] an edge's samples may lie from the face's surface.
RHINO_TRIM_TOLERANCE = 1e-6


def _face_loops(brep, face, surface: NurbsSurface) -> tuple[np.ndarray, ...]:
    """A trimmed .3dm face's loops in ``surface``'s parameters: each trim's 3D edge sampled, the
    pieces chained end to start (each turned where its far end meets the chain), and put on the
    surface by closest points (:func:`~bhem_hpc.geometry.projection.closest_points`)."""
    from bhem_hpc.geometry.projection import closest_points
    from bhem_hpc.geometry.trim import close_loop

    size = float(np.ptp(surface.control.reshape(-1, 3), axis=0).max()) or 1.0
    loops = []
    for loop in face.Loops:
        chain = None
        for trim in loop.Trims:
            edge = brep.Edges[trim.EdgeIndex]
            t = np.linspace(edge.Domain.T0, edge.Domain.T1, RHINO_TRIM_SAMPLES + 1)
            piece = np.array([[q.X, q.Y, q.Z] for q in (edge.PointAt(float(v)) for v in t)])
            if chain is None:
                chain = piece
                continue
            if np.linalg.norm(piece[-1] - chain[-1]) < np.linalg.norm(piece[0] - chain[-1]):
                piece = piece[::-1]
            chain = np.concatenate([chain, piece[1:]])
        parameters, _, distance = closest_points(surface, chain)
        if distance.max() > RHINO_TRIM_TOLERANCE * size:
            raise SurfaceError(f"{surface.name}: a trim edge lies {distance.max():.3g} from the face's surface")
        loops.append(close_loop(parameters))
    return tuple(loops)


def _write_rhino(path: Path, parts: Sequence[NurbsSurface]) -> None:
    import rhino3dm

    model = rhino3dm.File3dm()
    for part in parts:
        (n, m), (p, q) = part.control.shape[:2], part.degrees
        surface = rhino3dm.NurbsSurface.Create(3, True, p + 1, q + 1, n, m)
        for i, knot in enumerate(part.u.knots[1:-1]):
            surface.KnotsU[i] = float(knot)
        for j, knot in enumerate(part.v.knots[1:-1]):
            surface.KnotsV[j] = float(knot)
        homogeneous = part.homogeneous
        for i in range(n):
            for j in range(m):
                surface.Points[i, j] = rhino3dm.Point4d(*(float(x) for x in homogeneous[i, j]))
        attributes = rhino3dm.ObjectAttributes()
        attributes.Name = part.name
        model.Objects.AddSurface(surface, attributes)
    if not model.Write(str(path), 7):
        raise SurfaceError(f"{path}: rhino3dm could not write the file")
