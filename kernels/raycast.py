"""Ray casting against a triangle surface and a textured, shaded pinhole render (thesis
chapter 7: a synthetic "real" object seen by one camera; image features lifted onto the model
surface along their camera rays).

Rays start at one origin (the optical centre, m) and have unit world directions, so ray
parameters are distances in metres. A hit on triangle ``f = (i, j, k)`` with barycentrics
``(u, v)`` from :func:`warp.mesh_query_ray` is the point ``u p_i + v p_j + (1 - u - v) p_k``
(Woop's watertight test in Warp's ``intersect.h``).

The texture is attached to the material: it is evaluated at the REST position of the hit point
(interpolated from the triangle's rest vertices), so it moves and stretches with the object.
It is 3D value noise on an integer lattice (a PCG hash of the lattice point and a seed),
three octaves on rotated lattices, with a contrast stretch that turns smooth blobs into the sharp, cornered
spots Lucas-Kanade tracking needs.
"""

import warp as wp

NOISE_OCTAVES = wp.constant(3)


@wp.func
def hash_u32(x: wp.uint32) -> wp.uint32:
    """PCG output permutation of one 32-bit word (an integer hash; all constants < 2^31)."""
    state = x * wp.uint32(747796405) + wp.uint32(1013904223)
    word = ((state >> ((state >> wp.uint32(28)) + wp.uint32(4))) ^ state) * wp.uint32(277803737)
    return (word >> wp.uint32(22)) ^ word


@wp.func
def lattice_value(ix: int, iy: int, iz: int, seed: wp.uint32) -> float:
    """Pseudo-random value in [0, 1) of the integer lattice point ``(ix, iy, iz)``."""
    h = hash_u32(seed ^ wp.uint32(ix))
    h = hash_u32(h ^ wp.uint32(iy))
    h = hash_u32(h ^ wp.uint32(iz))
    return float(h >> wp.uint32(8)) * (1.0 / 16777216.0)


@wp.func
def fade(t: float) -> float:
    """Quintic smoothstep ``6t^5 - 15t^4 + 10t^3`` (C2 interpolation weight)."""
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@wp.func
def value_noise(p: wp.vec3, seed: wp.uint32) -> float:
    """Value noise in [0, 1) at ``p`` (lattice units): smooth interpolation of the lattice
    values of the 8 corners of the cell holding ``p``."""
    fx = wp.floor(p[0])
    fy = wp.floor(p[1])
    fz = wp.floor(p[2])
    ix = int(fx)
    iy = int(fy)
    iz = int(fz)
    tx = fade(p[0] - fx)
    ty = fade(p[1] - fy)
    tz = fade(p[2] - fz)
    c00 = wp.lerp(lattice_value(ix, iy, iz, seed), lattice_value(ix + 1, iy, iz, seed), tx)
    c10 = wp.lerp(lattice_value(ix, iy + 1, iz, seed), lattice_value(ix + 1, iy + 1, iz, seed), tx)
    c01 = wp.lerp(lattice_value(ix, iy, iz + 1, seed), lattice_value(ix + 1, iy, iz + 1, seed), tx)
    c11 = wp.lerp(lattice_value(ix, iy + 1, iz + 1, seed), lattice_value(ix + 1, iy + 1, iz + 1, seed), tx)
    return wp.lerp(wp.lerp(c00, c10, ty), wp.lerp(c01, c11, ty), tz)


@wp.func
def texture_value(rest: wp.vec3, seed: int, inv_scale: float, contrast: float) -> float:
    """Procedural texture in [0, 1] at the rest position ``rest`` (m).

    ``inv_scale`` (1/m) is one over the feature size; octave ``o`` has frequency ``2^o`` and
    weight ``2^-o`` (weights normalised to sum 1). The sum is stretched about 0.5 by
    ``contrast`` and clamped to [0, 1].
    """
    # every octave's lattice is turned by a further fixed rotation, so the lattice axes do
    # not show as blocky, axis-aligned edges in the image
    turn = wp.mat33(0.0, 0.8, 0.6, -0.8, 0.36, -0.48, -0.6, -0.48, 0.64)
    p = turn * (rest * inv_scale)
    total = float(0.0)
    weight = float(1.0)
    weights = float(0.0)
    for o in range(NOISE_OCTAVES):
        octave_seed = hash_u32(wp.uint32(seed) + wp.uint32(o) * wp.uint32(1664525))
        total += weight * value_noise(p, octave_seed)
        weights += weight
        weight *= 0.5
        p = turn * (2.0 * p)
    return wp.clamp(0.5 + contrast * (total / weights - 0.5), 0.0, 1.0)


@wp.kernel
def cast_rays(
    mesh: wp.uint64,
    origin: wp.vec3,
    directions: wp.array(dtype=wp.vec3),
    max_distance: float,
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    distance: wp.array(dtype=float),
):
    """One thread per ray from ``origin`` (m) along the unit ``directions[r]``: the closest
    triangle ``face[r]`` (-1 on a miss), the barycentrics ``(u, v)`` of its first two vertices
    (zero on a miss) and the distance (m; ``inf`` on a miss) within ``max_distance`` (m)."""
    r = wp.tid()
    q = wp.mesh_query_ray(mesh, origin, directions[r], max_distance)
    if q.result:
        face[r] = q.face
        bary[r] = wp.vec2(q.u, q.v)
        distance[r] = q.t
    else:
        face[r] = -1
        bary[r] = wp.vec2(0.0, 0.0)
        distance[r] = wp.inf


@wp.func
def to_byte(x: float) -> wp.uint8:
    """A colour channel in [0, 1] to 0..255 (rounded, clamped)."""
    return wp.uint8(int(wp.clamp(x, 0.0, 1.0) * 255.0 + 0.5))


@wp.kernel
def render_textured(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    rest_points: wp.array(dtype=wp.vec3),
    origin: wp.vec3,
    directions: wp.array(dtype=wp.vec3),
    max_distance: float,
    seed: int,
    inv_scale: float,
    contrast: float,
    ambient: float,
    dark: wp.vec3,
    light: wp.vec3,
    background: wp.vec3,
    image: wp.array(dtype=wp.uint8, ndim=2),
    mask: wp.array(dtype=wp.uint8),
):
    """Cast and shade in one pass, one thread per pixel ``r`` (row-major).

    A hit is coloured ``mix(dark, light, texture(rest point))`` times the Lambert factor
    ``ambient + (1 - ambient) |n . d|`` (light at the camera; ``n`` the triangle's unit
    geometric normal, ``d`` the ray); a miss gets the flat ``background``. Colours are in
    [0, 1] in the channel order of ``image`` (``(pixels, 3)`` bytes); ``mask[r]`` is 1 on the
    object, 0 elsewhere.
    """
    r = wp.tid()
    d = directions[r]
    q = wp.mesh_query_ray(mesh, origin, d, max_distance)
    color = background
    mask[r] = wp.uint8(0)
    if q.result:
        f = q.face
        rest = (
            q.u * rest_points[indices[3 * f]]
            + q.v * rest_points[indices[3 * f + 1]]
            + (1.0 - q.u - q.v) * rest_points[indices[3 * f + 2]]
        )
        s = texture_value(rest, seed, inv_scale, contrast)
        n_len = wp.length(q.normal)
        lambert = float(1.0)
        if n_len > 0.0:
            lambert = wp.abs(wp.dot(q.normal, d)) / n_len
        color = wp.lerp(dark, light, s) * (ambient + (1.0 - ambient) * lambert)
        mask[r] = wp.uint8(1)
    image[r, 0] = to_byte(color[0])
    image[r, 1] = to_byte(color[1])
    image[r, 2] = to_byte(color[2])
