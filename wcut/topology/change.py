"""The record of one topological event: how the new mesh derives from the old one.

A cut, a crack or a detected tear changes the mesh locally. :class:`TopologyChange` says, in
the old mesh's numbering, where every vertex and element of the new mesh comes from, so that
:meth:`wcut.model.Model.rebuild` can lay out the flat arrays again and carry the state over by
interpolation (DESIGN.md, "How data flows"): positions, velocities and rest positions of new
vertices are barycentric combinations of old ones, never guesses.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import chain

import numpy as np


def _compact_index(base_slots: np.ndarray):
    """The map from a slot live at the start of a change to its index among those slots
    (``base_slots`` ascending): the identity when no slot was free, else a lookup table.
    Either is a gather, cheaper than a binary search of every element."""
    count = len(base_slots)
    if count == 0 or base_slots[-1] == count - 1:
        return lambda slots: np.asarray(slots, dtype=np.int64)
    table = np.full(int(base_slots[-1]) + 1, -1, dtype=np.int64)
    table[base_slots] = np.arange(count)
    return lambda slots: table[np.asarray(slots, dtype=np.int64)]


def _padded_rows(expressions: list[dict[int, float]], lengths: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Sources (R, width) and weights (R, width) of vertex expressions {source: weight} (of
    ``lengths`` entries), in their order, padded with the first source and weight 0
    (flattened once: a list of rows costs a Python object per entry)."""
    total = int(lengths.sum())
    flat_sources = np.fromiter(chain.from_iterable(expressions), dtype=np.int64, count=total)
    flat_weights = np.fromiter(chain.from_iterable(e.values() for e in expressions), dtype=np.float64, count=total)
    starts = np.cumsum(lengths) - lengths
    row, column = np.repeat(np.arange(len(expressions)), lengths), np.arange(total) - np.repeat(starts, lengths)
    sources = np.repeat(flat_sources[starts][:, None], width, axis=1)
    weights = np.zeros((len(expressions), width))
    sources[row, column], weights[row, column] = flat_sources, flat_weights
    return sources, weights


def _journal_vertices(journal) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray, np.ndarray]:
    """The journal's expressed vertices (R,) with their sources and weights (R, width), the
    width (at least 4), and the created vertices with the base slots they were created in
    (those expressed), all in the journal's order."""
    expressions = list(journal.expression.values())
    rows = np.fromiter(journal.expression, dtype=np.int64, count=len(expressions))
    lengths = np.fromiter(map(len, expressions), dtype=np.int64, count=len(expressions))
    width = max(4, int(lengths.max(initial=0)))
    sources, weights = _padded_rows(expressions, lengths, width)
    created = np.fromiter(journal.vertex_origin.keys(), dtype=np.int64, count=len(journal.vertex_origin))
    created_in = np.fromiter(journal.vertex_origin.values(), dtype=np.int64, count=len(created))
    expressed = np.isin(created, rows)
    return rows, sources, weights, width, created[expressed], created_in[expressed]


def _removed_vertices(journal) -> np.ndarray:
    """The vertices (numbered before) of the base elements the journal's change removed."""
    return np.array(sorted(journal.removed_vertices), dtype=np.int64)


def _slot_hints(journal, new_slots: np.ndarray, origins: np.ndarray, count_after: int) -> dict:
    """The reparented and rewired elements of a change whose slots are the elements' indices
    before and after (``new_slots`` and the base slots they lie in, ``origins``)."""
    count = min(len(journal.base_slots), count_after)
    moved_in = np.sort(new_slots[(origins != new_slots) & (new_slots < count)])
    return {"reparented_elements": np.concatenate([moved_in, np.arange(count, count_after, dtype=np.int64)]),
            "rewired_elements": np.array(sorted(t for t in journal.rewired if t < count), dtype=np.int64)}


@dataclass(frozen=True)
class TopologyChange:
    """How mesh B (after) derives from mesh A (before); indices are compact mesh indices.

    Attributes:
        vertex_count_before, vertex_count_after, element_count_before, element_count_after.
        vertex_sources: (V_B, K) vertices of A, and
        vertex_weights: (V_B, K) weights, such that any vertex attribute of B (rest position,
            position, velocity) is ``sum_k weights[v, k] * attribute_A[sources[v, k]]``.
            An untouched vertex has itself with weight 1; a duplicate has its original.
        vertex_parent_element: (V_B,) element of A in which a new vertex was created (-1 for
            vertices of A, moved or not, and for duplicates).
        new_vertices: vertices of B that A did not have (created or duplicated).
        moved_vertices: vertices of A whose position changed (snapped).
        element_parent: (E_B,) element of A each element of B lies in, whose material it takes.
        element_rest_changed: (E_B,) True where the element's rest shape is new (added elements
            and elements around a moved vertex): their rest data must be recomputed.
        removed_elements: elements of A that B does not have.
        added_elements: elements of B that A did not have.
    """

    vertex_count_before: int
    vertex_count_after: int
    element_count_before: int
    element_count_after: int
    vertex_sources: np.ndarray
    vertex_weights: np.ndarray
    vertex_parent_element: np.ndarray
    new_vertices: np.ndarray
    moved_vertices: np.ndarray
    element_parent: np.ndarray
    element_rest_changed: np.ndarray
    removed_elements: np.ndarray
    added_elements: np.ndarray
    # What the record's maker knows, so that Model.rebuild need not find it by scanning the
    # mesh (None: unknown, scan). Each must be exactly what the scan gives.
    #: elements after whose parent is not the element of the same index before, ascending
    reparented_elements: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: vertices after not simply the vertex of the same index before (created, moved,
    #: interpolated), ascending
    touched_vertices: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: elements below both element counts whose vertices may differ from before although
    #: neither their parent nor their rest shape changed (a vertex swapped for its copy)
    rewired_elements: np.ndarray | None = field(default=None, repr=False, compare=False)
    #: vertices (numbered before) of the elements removed, ascending
    removed_vertices: np.ndarray | None = field(default=None, repr=False, compare=False)

    # What Model.rebuild reads: a few rows each (the journal's record answers without laying
    # out the whole-mesh arrays).
    def vertex_rows(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``vertex_sources[vertices]`` and ``vertex_weights[vertices]``."""
        return self.vertex_sources[vertices], self.vertex_weights[vertices]

    def element_parents(self, elements: np.ndarray) -> np.ndarray:
        """``element_parent[elements]``."""
        return self.element_parent[elements]

    def rest_changed_elements(self) -> np.ndarray:
        """``flatnonzero(element_rest_changed)``: the elements whose rest data is new."""
        return np.flatnonzero(self.element_rest_changed)

    @property
    def is_empty(self) -> bool:
        """True when the mesh did not change at all."""
        return (self.vertex_count_after == self.vertex_count_before and len(self.removed_elements) == 0
                and len(self.added_elements) == 0 and len(self.moved_vertices) == 0
                and not len(self.rest_changed_elements()))

    @classmethod
    def from_journal(cls, journal, topo) -> "TopologyChange":
        """The change recorded in ``journal`` since ``topo``'s :meth:`begin_change`. Where the
        slots are the elements' indices before and after and no vertex was renumbered (a cut
        of a mesh without free slots), it holds only what changed and lays out its whole-mesh
        arrays when they are first read: the cost follows the cut."""
        base_slots = journal.base_slots
        if not topo._free and journal.vertex_renumber is None and \
                (len(base_slots) == 0 or base_slots[-1] == len(base_slots) - 1):
            return _JournalChange.of(journal, topo)  # a slot is its element's index, before and after
        return cls._laid_out(journal, topo)

    @classmethod
    def _laid_out(cls, journal, topo) -> "TopologyChange":
        """:meth:`from_journal` with every array laid out (whatever the slots)."""
        base_slots = journal.base_slots
        index = _compact_index(base_slots)
        slots = topo.live_tets()
        origin = np.arange(topo.slot_count, dtype=np.int64)  # slot -> base slot it lies in
        added_mask = np.zeros(topo.slot_count, dtype=bool)
        reshaped = np.zeros(topo.slot_count, dtype=bool)
        new_slots = np.fromiter(journal.origin.keys(), dtype=np.int64, count=len(journal.origin))
        origin[new_slots] = np.fromiter(journal.origin.values(), dtype=np.int64, count=len(journal.origin))
        added_mask[new_slots] = True
        if journal.reshaped:
            reshaped[list(journal.reshaped)] = True
        hints = {}
        if len(slots) == topo.slot_count:  # every slot lives: no gathers over the whole mesh
            element_parent, rest_changed, added = index(origin), added_mask | reshaped, np.flatnonzero(added_mask)
            if len(base_slots) == 0 or base_slots[-1] == len(base_slots) - 1:  # nor before: a slot is its index
                hints = _slot_hints(journal, new_slots, origin[new_slots], len(slots))
        else:
            element_parent = index(origin[slots])
            rest_changed = added_mask[slots] | reshaped[slots]
            added = np.flatnonzero(added_mask[slots])
        removed = index(np.array(sorted(journal.removed_base), dtype=np.int64))

        v_a, v_b = journal.base_vertex_count, topo.vertex_count
        rows, row_sources, row_weights, width, created, created_in = _journal_vertices(journal)
        identity = np.arange(v_b, dtype=np.int64) if journal.vertex_renumber is None else journal.vertex_renumber
        sources = np.repeat(identity[:, None], width, axis=1)
        weights = np.zeros((v_b, width))
        weights[:, 0] = 1.0
        sources[rows], weights[rows] = row_sources, row_weights
        parent_element = np.full(v_b, -1, dtype=np.int64)
        parent_element[created] = index(created_in)
        moved = np.sort(rows[rows < v_a])
        if journal.vertex_renumber is None:
            hints["touched_vertices"] = np.concatenate([moved, np.arange(v_a, v_b, dtype=np.int64)])
            hints["removed_vertices"] = _removed_vertices(journal)
            if "rewired_elements" not in hints:  # the live slots rewired, at their indices after
                rewired = np.zeros(topo.slot_count, dtype=bool)
                rewired[list(journal.rewired)] = True
                rewired = np.flatnonzero(rewired[slots])
                hints["rewired_elements"] = rewired[rewired < min(len(base_slots), len(slots))]
        else:
            hints.pop("rewired_elements", None)  # every row may have new vertex numbers
        return cls(
            vertex_count_before=v_a, vertex_count_after=v_b,
            element_count_before=len(base_slots), element_count_after=len(slots),
            vertex_sources=sources, vertex_weights=weights, vertex_parent_element=parent_element,
            new_vertices=np.arange(v_a, max(v_a, v_b), dtype=np.int64), moved_vertices=moved,
            element_parent=element_parent, element_rest_changed=rest_changed,
            removed_elements=removed, added_elements=added, **hints,
        )


@dataclass
class _Sparse:
    """What a :class:`_JournalChange` holds instead of its whole-mesh arrays: the new slots
    and the slots they lie in (sorted), the elements with new rest data, the expressed
    vertices (sorted) with their sources and weights (padded to ``width``), the created
    vertices and the elements they were created in."""

    new_slots: np.ndarray
    new_slot_origins: np.ndarray
    rest_changed: np.ndarray
    rows: np.ndarray
    row_sources: np.ndarray
    row_weights: np.ndarray
    width: int
    created: np.ndarray
    created_in: np.ndarray


class _JournalChange(TopologyChange):
    """A :class:`TopologyChange` from a journal whose slots are the elements' indices before
    and after (no free slot) and whose vertices keep their numbers: it holds only what
    changed, and lays out the whole-mesh arrays (``vertex_sources``, ``element_parent``, ...)
    when they are first read. Its sparse answers (:meth:`vertex_rows`, ...) are what those
    arrays give. (A copy made by ``dataclasses.replace`` has them all laid out: a plain
    record.)"""

    _DENSE = ("vertex_sources", "vertex_weights", "vertex_parent_element", "element_parent",
              "element_rest_changed")

    @classmethod
    def of(cls, journal, topo) -> "_JournalChange":
        v_a, v_b, m_a, m_b = journal.base_vertex_count, topo.vertex_count, len(journal.base_slots), topo.slot_count
        new_slots = np.fromiter(journal.origin.keys(), dtype=np.int64, count=len(journal.origin))
        origins = np.fromiter(journal.origin.values(), dtype=np.int64, count=len(new_slots))
        rows, sources, weights, width, created, created_in = _journal_vertices(journal)
        by_slot, by_vertex = np.argsort(new_slots), np.argsort(rows)
        sparse = _Sparse(new_slots[by_slot], origins[by_slot],
                         np.union1d(new_slots, np.fromiter(journal.reshaped, dtype=np.int64, count=len(journal.reshaped))),
                         rows[by_vertex], sources[by_vertex], weights[by_vertex], width, created, created_in)
        moved = np.sort(rows[rows < v_a])
        change = object.__new__(cls)
        for name, value in dict(
                _sparse=sparse, vertex_count_before=v_a, vertex_count_after=v_b, element_count_before=m_a,
                element_count_after=m_b, new_vertices=np.arange(v_a, max(v_a, v_b), dtype=np.int64),
                moved_vertices=moved, removed_elements=np.array(sorted(journal.removed_base), dtype=np.int64),
                added_elements=sparse.new_slots,
                touched_vertices=np.concatenate([moved, np.arange(v_a, v_b, dtype=np.int64)]),
                removed_vertices=_removed_vertices(journal),
                **_slot_hints(journal, new_slots, origins, m_b)).items():
            object.__setattr__(change, name, value)
        return change

    def __getattr__(self, name: str):
        sparse = self.__dict__.get("_sparse")
        if name not in self._DENSE or sparse is None:
            raise AttributeError(name)
        v_b, m_b = self.vertex_count_after, self.element_count_after
        sources = np.repeat(np.arange(v_b, dtype=np.int64)[:, None], sparse.width, axis=1)
        weights = np.zeros((v_b, sparse.width))
        weights[:, 0] = 1.0
        sources[sparse.rows], weights[sparse.rows] = sparse.row_sources, sparse.row_weights
        parent_element = np.full(v_b, -1, dtype=np.int64)
        parent_element[sparse.created] = sparse.created_in
        element_parent = np.arange(m_b, dtype=np.int64)
        element_parent[sparse.new_slots] = sparse.new_slot_origins
        rest_changed = np.zeros(m_b, dtype=bool)
        rest_changed[sparse.rest_changed] = True
        for key, value in zip(self._DENSE, (sources, weights, parent_element, element_parent, rest_changed)):
            object.__setattr__(self, key, value)
        return getattr(self, name)

    def vertex_rows(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sparse = self.__dict__.get("_sparse")
        if sparse is None:
            return super().vertex_rows(vertices)
        vertices = np.asarray(vertices, dtype=np.int64)
        sources = np.repeat(vertices[:, None], sparse.width, axis=1)
        weights = np.zeros((len(vertices), sparse.width))
        weights[:, 0] = 1.0
        if len(sparse.rows):
            at = np.minimum(np.searchsorted(sparse.rows, vertices), len(sparse.rows) - 1)
            hit = sparse.rows[at] == vertices
            sources[hit], weights[hit] = sparse.row_sources[at[hit]], sparse.row_weights[at[hit]]
        return sources, weights

    def element_parents(self, elements: np.ndarray) -> np.ndarray:
        sparse = self.__dict__.get("_sparse")
        if sparse is None:
            return super().element_parents(elements)
        elements = np.asarray(elements, dtype=np.int64)
        if not len(sparse.new_slots):
            return elements.copy()
        at = np.minimum(np.searchsorted(sparse.new_slots, elements), len(sparse.new_slots) - 1)
        return np.where(sparse.new_slots[at] == elements, sparse.new_slot_origins[at], elements)

    def rest_changed_elements(self) -> np.ndarray:
        sparse = self.__dict__.get("_sparse")
        return super().rest_changed_elements() if sparse is None else sparse.rest_changed


def compose(first: TopologyChange, second: TopologyChange) -> TopologyChange:
    """The change from ``first``'s mesh before to ``second``'s mesh after, for two changes made
    one after the other (``second`` starts from ``first``'s mesh after), in the numbering
    conventions of the shell operators: an element keeps its index unless replaced, new
    elements and vertices are appended. Vertex weights are multiplied out and merged per
    source, so interpolating through the composite equals interpolating twice."""
    if second.vertex_count_before != first.vertex_count_after or \
            second.element_count_before != first.element_count_after:
        raise ValueError("compose: the second change does not start from the first one's mesh")
    s1, w1, s2, w2 = first.vertex_sources, first.vertex_weights, second.vertex_sources, second.vertex_weights
    count = second.vertex_count_after
    itself = (s2[:, 0] == np.arange(count)) & (w2[:, 0] == 1.0) & (w2[:, 1:] == 0.0).all(axis=1)
    rows = {}
    for v in np.flatnonzero(~itself).tolist():
        merged: dict[int, float] = {}
        for s, w in zip(s2[v].tolist(), w2[v].tolist()):
            for s0, w0 in zip(s1[s].tolist(), w1[s].tolist()):
                if w != 0.0 and w0 != 0.0:
                    merged[s0] = merged.get(s0, 0.0) + w * w0
        rows[v] = merged or {int(s1[s2[v, 0], 0]): 0.0}
    width = max([s1.shape[1]] + [len(r) for r in rows.values()])
    kept = np.flatnonzero(itself)  # rows of the first change, as they are
    sources = np.empty((count, width), dtype=np.int64)
    weights = np.zeros((count, width))
    sources[kept] = np.pad(s1[kept], ((0, 0), (0, width - s1.shape[1])), mode="edge")
    weights[kept, :s1.shape[1]] = w1[kept]
    for v, r in rows.items():
        sources[v] = list(r) + [next(iter(r))] * (width - len(r))
        weights[v] = list(r.values()) + [0.0] * (width - len(r))
    parent = np.where(second.vertex_parent_element >= 0,
                      first.element_parent[np.maximum(second.vertex_parent_element, 0)], -1)
    # a vertex second did not create (kept, or a copy with weight 1 on one vertex) keeps the
    # parent first gave that vertex
    copied = (parent < 0) & (w2[:, 0] == 1.0) & (w2[:, 1:] == 0.0).all(axis=1)
    parent[copied] = first.vertex_parent_element[s2[copied, 0]]
    element_parent = first.element_parent[second.element_parent]
    first_added = np.zeros(first.element_count_after, dtype=bool)
    first_added[first.added_elements] = True
    removed = np.union1d(first.removed_elements,
                         first.element_parent[second.removed_elements[~first_added[second.removed_elements]]])
    added = np.union1d(second.added_elements,
                       first.added_elements[first.added_elements < second.element_count_after])
    moved = np.union1d(first.moved_vertices, second.moved_vertices[second.moved_vertices < first.vertex_count_before])
    return TopologyChange(
        vertex_count_before=first.vertex_count_before, vertex_count_after=second.vertex_count_after,
        element_count_before=first.element_count_before, element_count_after=second.element_count_after,
        vertex_sources=sources, vertex_weights=weights, vertex_parent_element=parent,
        new_vertices=np.arange(first.vertex_count_before, second.vertex_count_after, dtype=np.int64),
        moved_vertices=moved.astype(np.int64), element_parent=element_parent,
        element_rest_changed=second.element_rest_changed | first.element_rest_changed[second.element_parent],
        removed_elements=removed.astype(np.int64), added_elements=added.astype(np.int64),
    )
