// Closed, outward-oriented triangle meshes of simple solids, for tests, examples and the
// procedural demo. All are centred at the origin; lengths in metres.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <functional>

namespace fascicle {

// Axis-aligned box with the given half extents; 12 triangles.
TriMesh make_box(const Vec3& half_extents);

// Sphere by recursive subdivision of an icosahedron (20 * 4^subdivisions triangles), vertices on
// the sphere.
TriMesh make_icosphere(double radius, int subdivisions);

// Ellipsoid: an icosphere scaled by the radii along x, y, z.
TriMesh make_ellipsoid(const Vec3& radii, int subdivisions);

// Cylinder of the given radius and height along z (z in [-h/2, h/2]), `segments` around, `rings`
// bands along the axis, flat capped ends (a centre vertex per cap).
TriMesh make_cylinder(double radius, double height, int segments, int rings = 1);

// Torus around the z axis: distance `major` from the axis to the tube centre, tube radius `minor`.
TriMesh make_torus(double major, double minor, int major_segments, int minor_segments);

// A closed spindle along z from z0 to z1: `rings` circles of `segments` vertices at
// t = 1/(rings+1) ... rings/(rings+1) with radius radius(t) > 0, closed by one apex vertex at
// each end. A generic shape for fusiform muscles and long bones.
TriMesh make_spindle(double z0, double z1, int segments, int rings,
                     const std::function<double(double t)>& radius);

}  // namespace fascicle
