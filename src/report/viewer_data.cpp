// Binary encoding of the viewer's mesh and frame files (layout in docs/viewer.md).
#include "fascicle/report/viewer_data.hpp"

#include "fascicle/core/error.hpp"

#include <bit>
#include <cmath>
#include <cstring>

namespace fascicle {
namespace {

static_assert(std::endian::native == std::endian::little, "the viewer files are little-endian");

class ByteWriter {
 public:
  template <class T>
  void put(T v) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    out_.append(b, sizeof(T));
  }
  void put_tag(const char* tag) { out_.append(tag, 4); }
  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

class ByteReader {
 public:
  ByteReader(std::string_view bytes, const std::string& what) : bytes_(bytes), what_(what) {}
  template <class T>
  T get() {
    if (at_ + sizeof(T) > bytes_.size())
      throw_bad_input(what_ + " is truncated (" + std::to_string(bytes_.size()) + " bytes)",
                      {.suggestion = "write the run again"});
    T v;
    std::memcpy(&v, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return v;
  }
  // A count that must fit in the remaining bytes at `min_bytes_each`.
  uint32_t get_count(size_t min_bytes_each) {
    const auto n = get<uint32_t>();
    if (static_cast<uint64_t>(n) * min_bytes_each > bytes_.size() - at_)
      throw_bad_input(what_ + " has an impossible count " + std::to_string(n),
                      {.suggestion = "the file is damaged: write the run again"});
    return n;
  }
  void expect_tag(const char* tag) {
    if (bytes_.size() < 4 || std::memcmp(bytes_.data(), tag, 4) != 0)
      throw_bad_input(what_ + " is not a fascicle viewer file (no '" + std::string(tag) + "' tag)",
                      {.suggestion = "write the run again with the report writer"});
    at_ = 4;
  }
  bool at_end() const { return at_ == bytes_.size(); }

 private:
  std::string_view bytes_;
  std::string what_;
  size_t at_ = 0;
};

struct Quantiser {
  Vec3 lo, scale;  // q = round((x − lo) ∘ scale)
  explicit Quantiser(const ViewerBox& box) : lo(box.lo) {
    const Vec3 extent = box.hi - box.lo;
    for (int k = 0; k < 3; ++k) scale[k] = extent[k] > 0 ? 65535.0 / extent[k] : 0.0;
  }
  uint16_t encode(double x, int k) const {
    if (!std::isfinite(x)) return 0;  // a failed frame's NaN: no valid code, keep the cast defined
    const double q = std::round((x - lo[k]) * scale[k]);
    return static_cast<uint16_t>(std::clamp(q, 0.0, 65535.0));
  }
  double decode(uint16_t q, int k) const { return scale[k] > 0 ? lo[k] + q / scale[k] : lo[k]; }
};

void put_points(ByteWriter& w, const Points3& P, PositionEncoding enc, const Quantiser& quant) {
  for (Eigen::Index i = 0; i < P.rows(); ++i)
    for (int k = 0; k < 3; ++k) {
      if (enc == PositionEncoding::float32)
        w.put(static_cast<float>(P(i, k)));
      else
        w.put(quant.encode(P(i, k), k));
    }
}

Points3 get_points(ByteReader& r, uint32_t n, PositionEncoding enc, const Quantiser& quant) {
  Points3 P(n, 3);
  for (uint32_t i = 0; i < n; ++i)
    for (int k = 0; k < 3; ++k)
      P(i, k) = enc == PositionEncoding::float32 ? static_cast<double>(r.get<float>())
                                                 : quant.decode(r.get<uint16_t>(), k);
  return P;
}

void extend(ViewerBox& box, bool& any, const Points3& P) {
  if (P.rows() == 0 || !P.allFinite()) return;  // non-finite points do not stretch the box
  const Vec3 lo = P.colwise().minCoeff().transpose(), hi = P.colwise().maxCoeff().transpose();
  box.lo = any ? box.lo.cwiseMin(lo).eval() : lo;
  box.hi = any ? box.hi.cwiseMax(hi).eval() : hi;
  any = true;
}

}  // namespace

std::string encode_viewer_frame(const ViewerFrame& frame, PositionEncoding encoding, const ViewerBox& box) {
  const Quantiser quant(box);
  ByteWriter w;
  w.put_tag("FVF1");
  w.put(static_cast<uint32_t>(encoding));
  w.put(frame.time_s);
  w.put(static_cast<uint32_t>(frame.X_ground_body.size()));
  w.put(static_cast<uint32_t>(frame.muscles.size()));
  // Body poses: 4×4 column-major (three.js Matrix4.fromArray order).
  for (const Transform& X : frame.X_ground_body)
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) w.put(static_cast<float>(X.matrix()(r, c)));
  for (const ViewerMuscleFrame& m : frame.muscles) {
    w.put(static_cast<uint32_t>(m.surface.rows()));
    w.put(static_cast<uint32_t>(m.action_line.rows()));
    w.put(static_cast<uint32_t>(m.fibres.size()));
    w.put(static_cast<uint32_t>(m.fibre_strain.size()));
    for (const Points3& f : m.fibres) w.put(static_cast<uint32_t>(f.rows()));
  }
  for (const ViewerMuscleFrame& m : frame.muscles) {
    put_points(w, m.surface, encoding, quant);
    put_points(w, m.action_line, encoding, quant);
    for (const Points3& f : m.fibres) put_points(w, f, encoding, quant);
  }
  for (const ViewerMuscleFrame& m : frame.muscles)
    for (Eigen::Index k = 0; k < m.fibre_strain.size(); ++k) w.put(static_cast<float>(m.fibre_strain[k]));
  return w.take();
}

ViewerFrame decode_viewer_frame(std::string_view bytes, const ViewerBox& box, const std::string& what) {
  ByteReader r(bytes, what);
  r.expect_tag("FVF1");
  const auto encoding = static_cast<PositionEncoding>(r.get<uint32_t>());
  if (encoding != PositionEncoding::float32 && encoding != PositionEncoding::uint16)
    throw_bad_input(what + " has an unknown position encoding");
  const Quantiser quant(box);
  ViewerFrame frame;
  frame.time_s = r.get<double>();
  const uint32_t num_bodies = r.get_count(64);
  const uint32_t num_muscles = r.get_count(16);
  for (uint32_t b = 0; b < num_bodies; ++b) {
    Transform X = Transform::Identity();
    for (int c = 0; c < 4; ++c)
      for (int row = 0; row < 4; ++row) X.matrix()(row, c) = r.get<float>();
    frame.X_ground_body.push_back(X);
  }
  struct Counts {
    uint32_t surface, action, strain;
    std::vector<uint32_t> fibres;
  };
  std::vector<Counts> counts(num_muscles);
  for (Counts& c : counts) {
    c.surface = r.get_count(6);
    c.action = r.get_count(6);
    const uint32_t nf = r.get_count(4);
    c.strain = r.get_count(4);
    for (uint32_t k = 0; k < nf; ++k) c.fibres.push_back(r.get_count(6));
  }
  frame.muscles.resize(num_muscles);
  for (uint32_t m = 0; m < num_muscles; ++m) {
    ViewerMuscleFrame& mf = frame.muscles[m];
    mf.surface = get_points(r, counts[m].surface, encoding, quant);
    mf.action_line = get_points(r, counts[m].action, encoding, quant);
    for (uint32_t n : counts[m].fibres) mf.fibres.push_back(get_points(r, n, encoding, quant));
  }
  for (uint32_t m = 0; m < num_muscles; ++m) {
    frame.muscles[m].fibre_strain.resize(counts[m].strain);
    for (uint32_t k = 0; k < counts[m].strain; ++k) frame.muscles[m].fibre_strain[k] = r.get<float>();
  }
  if (!r.at_end()) throw_bad_input(what + " has trailing bytes", {.suggestion = "write the run again"});
  return frame;
}

std::string encode_viewer_mesh(const ViewerMesh& mesh) {
  ByteWriter w;
  w.put_tag("FVM1");
  w.put(static_cast<uint32_t>(mesh.body_vertices.size()));
  for (size_t b = 0; b < mesh.body_vertices.size(); ++b) {
    const Points3& V = mesh.body_vertices[b];
    const Triangles& F = mesh.body_triangles.at(b);
    w.put(static_cast<uint32_t>(V.rows()));
    w.put(static_cast<uint32_t>(F.rows()));
    for (Eigen::Index i = 0; i < V.rows(); ++i)
      for (int k = 0; k < 3; ++k) w.put(static_cast<float>(V(i, k)));
    for (Eigen::Index i = 0; i < F.rows(); ++i)
      for (int k = 0; k < 3; ++k) w.put(static_cast<uint32_t>(F(i, k)));
  }
  w.put(static_cast<uint32_t>(mesh.muscle_triangles.size()));
  for (const Triangles& F : mesh.muscle_triangles) {
    w.put(static_cast<uint32_t>(F.rows()));
    for (Eigen::Index i = 0; i < F.rows(); ++i)
      for (int k = 0; k < 3; ++k) w.put(static_cast<uint32_t>(F(i, k)));
  }
  return w.take();
}

ViewerMesh decode_viewer_mesh(std::string_view bytes, const std::string& what) {
  ByteReader r(bytes, what);
  r.expect_tag("FVM1");
  ViewerMesh mesh;
  const uint32_t num_bodies = r.get_count(8);
  const auto get_triangles = [&](uint32_t n) {
    Triangles F(n, 3);
    for (uint32_t i = 0; i < n; ++i)
      for (int k = 0; k < 3; ++k) F(i, k) = static_cast<int>(r.get<uint32_t>());
    return F;
  };
  for (uint32_t b = 0; b < num_bodies; ++b) {
    const uint32_t nv = r.get_count(12);
    const uint32_t nf = r.get_count(12);
    Points3 V(nv, 3);
    for (uint32_t i = 0; i < nv; ++i)
      for (int k = 0; k < 3; ++k) V(i, k) = r.get<float>();
    mesh.body_vertices.push_back(std::move(V));
    mesh.body_triangles.push_back(get_triangles(nf));
  }
  const uint32_t num_muscles = r.get_count(4);
  for (uint32_t m = 0; m < num_muscles; ++m) mesh.muscle_triangles.push_back(get_triangles(r.get_count(12)));
  if (!r.at_end()) throw_bad_input(what + " has trailing bytes", {.suggestion = "write the run again"});
  return mesh;
}

ViewerBox calc_viewer_box(const ViewerFrame& frame) {
  ViewerBox box;
  bool any = false;
  for (const ViewerMuscleFrame& m : frame.muscles) {
    extend(box, any, m.surface);
    extend(box, any, m.action_line);
    for (const Points3& f : m.fibres) extend(box, any, f);
  }
  return box;
}

ViewerBox merge_boxes(const ViewerBox& a, const ViewerBox& b) {
  return {a.lo.cwiseMin(b.lo), a.hi.cwiseMax(b.hi)};
}

ViewerBox pad_box(const ViewerBox& box, double min_extent_m) {
  ViewerBox out = box;
  for (int k = 0; k < 3; ++k) {
    const double missing = min_extent_m - (box.hi[k] - box.lo[k]);
    if (missing > 0) {
      out.lo[k] -= 0.5 * missing;
      out.hi[k] += 0.5 * missing;
    }
  }
  return out;
}

std::string encode_base64(std::string_view bytes) {
  static constexpr char table[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (uint8_t(bytes[i]) << 16) | (uint8_t(bytes[i + 1]) << 8) | uint8_t(bytes[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out.push_back(table[(v >> s) & 63]);
  }
  if (i < bytes.size()) {
    uint32_t v = uint8_t(bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= uint8_t(bytes[i + 1]) << 8;
    out.push_back(table[(v >> 18) & 63]);
    out.push_back(table[(v >> 12) & 63]);
    out.push_back(i + 1 < bytes.size() ? table[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

}  // namespace fascicle
