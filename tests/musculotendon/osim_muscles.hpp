// Every muscle of an OpenSim model in ../shared/data/opensim/models, compiled by the musculotendon
// module alone (shared by the musculotendon tests; no skeleton or paths).
#pragma once

#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>
#include <pugixml.hpp>

#include <string>
#include <vector>

namespace fascicle::test {

inline std::vector<Musculotendon> load_osim_musculotendons(const std::string& file) {
  const std::string path = data_path("opensim/models/" + file).string();
  pugi::xml_document doc;
  EXPECT_TRUE(doc.load_file(path.c_str())) << path;
  std::vector<Musculotendon> out;
  for (const pugi::xpath_node& x : doc.select_nodes("//*[@name]"))
    if (is_osim_muscle_element(x.node())) out.push_back(compile_musculotendon(parse_osim_muscle(x.node(), path)));
  return out;
}

}  // namespace fascicle::test
