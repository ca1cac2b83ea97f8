// A CPU triangle rasteriser for the synthetic benchmark videos: depth-tested, perspective-correct, near-plane
// clipped, with trilinear mip-mapped textures (no shimmering that a tracker would follow) and Lambert shading.
//
// Conventions (the same as m3c.viz.raster, which the tests use as the reference): OpenCV camera frame (x right,
// y down, z forward), intrinsics (fx, fy, cx, cy), pixel (i, j)'s centre at image coordinates (i, j). A pixel is
// covered when its centre lies inside a triangle; centres exactly on an edge belong to the triangle whose edge is a
// top or left edge. Depth is the camera z of the surface. Triangles are clipped against z = near, so geometry that
// extends behind the camera (a ground plane) is drawn correctly.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <vector>

#include "util/pinhole.h"

namespace m3c::render {

// An RGB texture that repeats in both directions, with its mip chain: level 0 is the image, each further level
// halves both sides by 2x2 box averaging, down to one texel. Width and height must be powers of two.
class Texture {
 public:
  // rgb: height x width x 3 floats, row-major.
  Texture(const float* rgb, int width, int height);

  int width() const { return levels_[0].width; }
  int height() const { return levels_[0].height; }
  int num_levels() const { return static_cast<int>(levels_.size()); }

  // Trilinear lookup at (u, v) in texels of level 0 (u along the width, texel centres at integer + 0.5), for a
  // pixel whose footprint spans `footprint` level-0 texels: level log2(footprint), clamped to the chain.
  void Sample(double u, double v, double footprint, float out[3]) const;
  // Bilinear lookup in one level (coordinates in that level's texels).
  void SampleLevel(int level, double u, double v, float out[3]) const;

 private:
  struct Level {
    int width, height;
    std::vector<float> rgb;
  };
  std::vector<Level> levels_;
};

// What one draw call paints. Exactly one of `texture` (with per-vertex uv) or `face_rgb` is set. The arrays are
// read during Draw(); the texture must outlive the frame's Resolve().
struct Material {
  std::shared_ptr<const Texture> texture;
  const double* uv = nullptr;         // V x 2, in level-0 texels
  const float* face_rgb = nullptr;    // F x 3, albedo in [0, 1]
  const double* normals = nullptr;    // V x 3 camera-frame vertex normals for smooth shading; null: face normals
  Eigen::Vector3d light{0.0, -1.0, 0.0};  // unit, camera frame, from the surface towards the light
  double ambient = 0.4;               // shade = albedo * (ambient + (1 - ambient) * max(0, n . light))
  int32_t id = 0;                     // written to the id buffer where this mesh is visible
  bool cull = false;                  // skip triangles seen from behind (closed meshes wound counter-clockwise)
};

// A triangle ready to scan, with what shades it.
struct ScreenTriangle;

// Colour (float RGB), depth (camera z, +inf where empty) and id (-1 where empty) buffers. Draw() clips, projects
// and queues triangles; the first read of a buffer rasterises everything queued in one pass, its rows split
// between threads (OpenMP), so that a frame costs one parallel region however many meshes it has.
class Frame {
 public:
  Frame(int width, int height, const float background[3]);
  ~Frame();
  int width() const { return width_; }
  int height() const { return height_; }
  const std::vector<float>& rgb() { Resolve(); return rgb_; }
  const std::vector<float>& depth() { Resolve(); return depth_; }
  const std::vector<int32_t>& ids() { Resolve(); return ids_; }

  // Queues triangles `faces` (F x 3 vertex ids) of `vertices` (V x 3, camera frame, metres), depth-tested against
  // everything drawn before and after (ties go to the earlier draw).
  void Draw(const Intrinsics& intrinsics, double near, const double* vertices, int num_vertices,
            const int32_t* faces, int num_faces, const Material& material);
  // Rasterises what is queued.
  void Resolve();

 private:
  struct Shading {
    std::shared_ptr<const Texture> texture;
    Eigen::Vector3d light;
    double ambient;
    int32_t id;
    bool smooth;
  };
  int width_, height_;
  std::vector<float> rgb_;
  std::vector<float> depth_;
  std::vector<int32_t> ids_;
  std::vector<Shading> shadings_;
  std::vector<Intrinsics> intrinsics_;  // per shading (a pixel's camera ray for two-sided lighting)
  std::vector<ScreenTriangle> queued_;
};

}  // namespace m3c::render
