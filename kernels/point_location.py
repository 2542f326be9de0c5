"""Point location in a tetrahedral mesh, in double precision (thesis 3.2: a point of the current
configuration keeps its barycentric coordinates in the element holding it, which maps it to
the rest configuration).

One thread per element, each testing every point against the sphere around its centre that
holds the element (centre: the mean of its corners; radius: its farthest corner), so the
launch costs elements x points sphere tests and a barycentric solve only where a point is
inside a sphere. Few points (a blade's samples) against the whole mesh: no search structure
to build first.
"""

import warp as wp

#: a point this far outside an element in barycentric terms still counts as inside it
INSIDE_TOL = wp.constant(wp.float64(1.0e-9))


@wp.func
def tet_corners(tets: wp.array(dtype=wp.vec4i), x: wp.array(dtype=wp.vec3d), i: int):
    """The four corners (m) of element ``tets[i]``."""
    tet = tets[i]
    return x[tet[0]], x[tet[1]], x[tet[2]], x[tet[3]]


@wp.func
def barycentric(inverse: wp.mat33d, c0: wp.vec3d, p: wp.vec3d) -> wp.vec4d:
    """The barycentric weights of ``p`` in the element with corner ``c0`` and ``inverse`` the
    inverse of its edge matrix (columns c1 - c0, c2 - c0, c3 - c0)."""
    local = inverse * (p - c0)
    return wp.vec4d(wp.float64(1.0) - (local[0] + local[1] + local[2]), local[0], local[1], local[2])


@wp.func
def element_sphere(c0: wp.vec3d, c1: wp.vec3d, c2: wp.vec3d, c3: wp.vec3d):
    """The centre (m) and the squared radius (m^2, grown by a relative 1e-9) of the sphere
    about the element's corner mean that holds it."""
    centre = wp.float64(0.25) * (c0 + c1 + c2 + c3)
    radius_sq = wp.max(wp.max(wp.length_sq(c0 - centre), wp.length_sq(c1 - centre)),
                       wp.max(wp.length_sq(c2 - centre), wp.length_sq(c3 - centre)))
    return centre, radius_sq * wp.float64(1.0 + 1.0e-9)


@wp.kernel
def locate_points(tets: wp.array(dtype=wp.vec4i), x: wp.array(dtype=wp.vec3d), points: wp.array(dtype=wp.vec3d),
                  nearest_sq: wp.array(dtype=wp.float64), hit_count: wp.array(dtype=wp.int32),
                  hit_point: wp.array(dtype=wp.int32), hit_element: wp.array(dtype=wp.int32),
                  hit_weights: wp.array(dtype=wp.vec4d)):
    """For element i (corners ``x[tets[i]]``): lowers ``nearest_sq[j]`` to the squared distance
    (m^2) of point j to its centre, and appends (point, element, barycentric weights) for every
    point inside it (weights at least ``-INSIDE_TOL``) to the hit lists, counted in
    ``hit_count[0]`` (hits past their capacity are counted, not written). ``nearest_sq``
    starts at inf, ``hit_count`` at 0."""
    i = wp.tid()
    c0, c1, c2, c3 = tet_corners(tets, x, i)
    centre, radius_sq = element_sphere(c0, c1, c2, c3)
    inverse = wp.mat33d()
    solved = bool(False)
    for j in range(points.shape[0]):
        p = points[j]
        gap = wp.length_sq(p - centre)
        wp.atomic_min(nearest_sq, j, gap)
        if gap <= radius_sq:
            if not solved:
                inverse = wp.inverse(wp.matrix_from_cols(c1 - c0, c2 - c0, c3 - c0))
                solved = True
            weights = barycentric(inverse, c0, p)
            if wp.min(wp.min(weights[0], weights[1]), wp.min(weights[2], weights[3])) >= -INSIDE_TOL:
                k = wp.atomic_add(hit_count, 0, 1)
                if k < hit_point.shape[0]:
                    hit_point[k] = j
                    hit_element[k] = i
                    hit_weights[k] = weights


@wp.kernel
def elements_near(tets: wp.array(dtype=wp.vec4i), x: wp.array(dtype=wp.vec3d), points: wp.array(dtype=wp.vec3d),
                  reach: wp.array(dtype=wp.float64), near: wp.array(dtype=wp.int32)):
    """Whether element i may hold a point within ``reach[j]`` (m) of one of ``points``: the
    centre of its sphere lies within ``reach[j]`` plus the sphere's radius."""
    i = wp.tid()
    c0, c1, c2, c3 = tet_corners(tets, x, i)
    centre, radius_sq = element_sphere(c0, c1, c2, c3)
    radius = wp.sqrt(radius_sq)
    found = int(0)
    for j in range(points.shape[0]):
        if wp.length(points[j] - centre) <= reach[j] + radius:
            found = 1
    near[i] = found
