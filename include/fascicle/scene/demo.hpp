// The embedded demo: a procedural right lower leg built in code (docs/demo.md). Bones: distal
// femur (welded to ground), tibia, fibula (welded to the tibia), talus, calcaneus and foot (welded
// to the talus); knee and ankle hinges. Muscles: soleus, medial and lateral gastrocnemius,
// tibialis anterior as closed spindle-shaped bellies with Ward et al. (2009) volumes, fibre
// lengths and pennation. Frame: x anterior, y superior, z lateral (right leg), OpenSim style;
// the ground frame is the femur frame, origin at the knee centre.
#pragma once

#include "fascicle/io/table.hpp"
#include "fascicle/scene/scene_spec.hpp"

namespace fascicle {

struct DemoScene {
  SceneSpec spec;
  Table motion;  // coordinates "knee_flexion" and "ankle_angle" in degrees, 2 s
};

// Knee flexion 0 → 60° → 0 and ankle angle −20° → +30° → −20° (dorsiflexion positive) over
// 2 s, smooth (cosine) profiles sampled at `samples_hz`. `muscle_resolution` scales the mesh
// density of the muscle bellies (1: about 2k triangles each).
DemoScene make_demo_leg(double samples_hz = 100.0, int muscle_resolution = 1);

}  // namespace fascicle
