"""Reading gmsh's first file format (``$NOD``/``$ELM``), in which SOFA ships its meshes.

meshio reads gmsh 2 and 4 (files that start with ``$MeshFormat``) but not this one. The format:
``$NOD``, the node count, one line ``number x y z`` per node, ``$ENDNOD``; then ``$ELM``, the
element count, one line ``number type physical elementary node-count node-numbers...`` per
element, ``$ENDELM``. Node numbers are labels, not positions, and need not be contiguous.
"""

from __future__ import annotations

import numpy as np

from .errors import MeshError

#: gmsh element type -> (meshio cell type, node count)
ELEMENT_TYPES = {1: ("line", 2), 2: ("triangle", 3), 3: ("quad", 4), 4: ("tetra", 4), 5: ("hexahedron", 8),
                 6: ("wedge", 6), 7: ("pyramid", 5), 8: ("line3", 3), 9: ("triangle6", 6), 11: ("tetra10", 10),
                 15: ("vertex", 1)}
#: gmsh numbers the last two edge nodes of a 10-node tetrahedron (2,3), (1,3); VTK and meshio (1,3), (2,3)
_TETRA10_TO_VTK = [0, 1, 2, 3, 4, 5, 6, 7, 9, 8]


def is_gmsh_v1(path: str) -> bool:
    """Whether the file's first word is ``$NOD`` (or ``$NOE``, an older spelling)."""
    with open(path, "rb") as f:
        head = f.read(256).lstrip()
    return head.startswith(b"$NOD") or head.startswith(b"$NOE")


def read(path: str):
    """The file as a ``meshio.Mesh`` (points in the file's node order, cells indexed into them).

    Raises:
        MeshError: a missing section, a count that disagrees with the lines, an unknown element
        type, or an element naming a node the file does not define; the message names the line.
    """
    import meshio

    with open(path, encoding="ascii", errors="replace") as f:
        lines = f.read().splitlines()
    name = path
    cursor = [0]

    def next_line(what: str) -> tuple[int, list[str]]:
        while cursor[0] < len(lines):
            cursor[0] += 1
            words = lines[cursor[0] - 1].split()
            if words:
                return cursor[0], words
        raise MeshError(f"{name}: cannot read mesh: the file ends before {what} (gmsh format 1)")

    def section(tag: str) -> int:
        number, words = next_line(tag)
        if words[0] not in tag.split("|"):
            raise MeshError(f"{name}: cannot read mesh: line {number}: expected {tag.split('|')[0]}, "
                            f"found {words[0]!r} (gmsh format 1)")
        number, words = next_line(f"the count after {tag}")
        try:
            return int(words[0])
        except ValueError:
            raise MeshError(f"{name}: cannot read mesh: line {number}: {words[0]!r} is not a count") from None

    node_count = section("$NOD|$NOE")
    labels, points = np.empty(node_count, dtype=np.int64), np.empty((node_count, 3))
    for i in range(node_count):
        number, words = next_line(f"node {i + 1} of {node_count}")
        try:
            labels[i], points[i] = int(words[0]), [float(w) for w in words[1:4]]
        except (ValueError, IndexError):
            raise MeshError(f"{name}: cannot read mesh: line {number}: a node is 'number x y z'") from None
    _end(next_line, "$ENDNOD|$ENDNOE", name)
    order = np.argsort(labels, kind="stable")
    if np.any(np.diff(labels[order]) == 0):
        raise MeshError(f"{name}: cannot read mesh: node number {labels[order][np.diff(labels[order]) == 0][0]} "
                        "is defined twice")

    element_count = section("$ELM")
    cells: dict[str, list] = {}
    for i in range(element_count):
        number, words = next_line(f"element {i + 1} of {element_count}")
        try:
            kind, count = int(words[1]), int(words[4])
            nodes = [int(w) for w in words[5:5 + count]]
        except (ValueError, IndexError):
            raise MeshError(f"{name}: cannot read mesh: line {number}: an element is "
                            "'number type physical elementary node-count nodes...'") from None
        if kind not in ELEMENT_TYPES or ELEMENT_TYPES[kind][1] != count or len(nodes) != count:
            raise MeshError(f"{name}: cannot read mesh: line {number}: element type {kind} with {count} nodes "
                            "is not one gmsh format 1 defines")
        cells.setdefault(ELEMENT_TYPES[kind][0], []).append(nodes)
    _end(next_line, "$ENDELM", name)

    blocks = []
    for kind, rows in cells.items():
        rows = np.asarray(rows, dtype=np.int64)
        position = np.searchsorted(labels[order], rows).clip(0, node_count - 1)
        missing = labels[order][position] != rows
        if missing.any():
            raise MeshError(f"{name}: cannot read mesh: a {kind} element names node {rows[missing][0]}, "
                            "which $NOD does not define")
        indices = order[position]
        blocks.append((kind, indices[:, _TETRA10_TO_VTK] if kind == "tetra10" else indices))
    return meshio.Mesh(points, blocks)


def _end(next_line, tag: str, name: str) -> None:
    number, words = next_line(tag.split("|")[0])
    if words[0] not in tag.split("|"):
        raise MeshError(f"{name}: cannot read mesh: line {number}: expected {tag.split('|')[0]}, found "
                        f"{words[0]!r}: the count before it disagrees with the lines (gmsh format 1)")
