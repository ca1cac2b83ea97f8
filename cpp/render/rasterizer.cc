#include "render/rasterizer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "util/check.h"

namespace m3c::render {

namespace {

bool IsPowerOfTwo(int n) { return n > 0 && (n & (n - 1)) == 0; }

// A vertex in the camera frame with the attributes interpolated across a triangle.
struct ClipVertex {
  Eigen::Vector3d p;
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
};

ClipVertex Lerp(const ClipVertex& a, const ClipVertex& b, double t) {
  return {a.p + t * (b.p - a.p), a.uv + t * (b.uv - a.uv), a.n + t * (b.n - a.n)};
}

// Sutherland-Hodgman against the plane z = near: at most 4 vertices out of 3.
int ClipNear(const std::array<ClipVertex, 3>& in, double near, std::array<ClipVertex, 4>& out) {
  int count = 0;
  for (int k = 0; k < 3; ++k) {
    const ClipVertex& a = in[k];
    const ClipVertex& b = in[(k + 1) % 3];
    const bool a_in = a.p.z() >= near, b_in = b.p.z() >= near;
    if (a_in) out[count++] = a;
    if (a_in != b_in) out[count++] = Lerp(a, b, (near - a.p.z()) / (b.p.z() - a.p.z()));
  }
  return count;
}

}  // namespace

// Screen positions, 1/z and attributes over z at the corners (so that their interpolation with screen-space
// barycentrics is perspective-correct), the pixel bounding box, and what shades it.
struct ScreenTriangle {
  std::array<Eigen::Vector2d, 3> s;
  std::array<double, 3> w;                // 1 / z
  std::array<Eigen::Vector2d, 3> uv_w;    // uv / z
  std::array<Eigen::Vector3d, 3> n_w;     // normal / z
  Eigen::Vector3d face_normal;
  std::array<float, 3> albedo;            // meshes with face colours
  int shading;
  int x0, x1, y0, y1;                     // inclusive pixel bounds, inside the image
};

Texture::Texture(const float* rgb, int width, int height) {
  M3C_CHECK(IsPowerOfTwo(width) && IsPowerOfTwo(height))
      << "texture sides must be powers of two (mip-mapping halves them), got " << width << " x " << height;
  levels_.push_back({width, height, std::vector<float>(rgb, rgb + static_cast<size_t>(width) * height * 3)});
  while (levels_.back().width > 1 || levels_.back().height > 1) {
    const Level& prev = levels_.back();
    Level next{std::max(1, prev.width / 2), std::max(1, prev.height / 2), {}};
    next.rgb.assign(static_cast<size_t>(next.width) * next.height * 3, 0.0f);
    const int sx = prev.width > 1 ? 2 : 1, sy = prev.height > 1 ? 2 : 1;
    const float scale = 1.0f / static_cast<float>(sx * sy);
    for (int j = 0; j < next.height; ++j) {
      for (int i = 0; i < next.width; ++i) {
        for (int dy = 0; dy < sy; ++dy) {
          for (int dx = 0; dx < sx; ++dx) {
            const float* src = &prev.rgb[(static_cast<size_t>(j * sy + dy) * prev.width + i * sx + dx) * 3];
            float* dst = &next.rgb[(static_cast<size_t>(j) * next.width + i) * 3];
            for (int c = 0; c < 3; ++c) dst[c] += scale * src[c];
          }
        }
      }
    }
    levels_.push_back(std::move(next));
  }
}

void Texture::SampleLevel(int level, double u, double v, float out[3]) const {
  const Level& l = levels_[level];
  const double x = u - 0.5, y = v - 0.5;
  const double fx = std::floor(x), fy = std::floor(y);
  const double ax = x - fx, ay = y - fy;
  // Sides are powers of two: wrapping is a mask (two's complement handles negative indices).
  const int mask_x = l.width - 1, mask_y = l.height - 1;
  const int i0 = static_cast<int>(fx) & mask_x, j0 = static_cast<int>(fy) & mask_y;
  const int i1 = (i0 + 1) & mask_x, j1 = (j0 + 1) & mask_y;
  const float* t00 = &l.rgb[(static_cast<size_t>(j0) * l.width + i0) * 3];
  const float* t10 = &l.rgb[(static_cast<size_t>(j0) * l.width + i1) * 3];
  const float* t01 = &l.rgb[(static_cast<size_t>(j1) * l.width + i0) * 3];
  const float* t11 = &l.rgb[(static_cast<size_t>(j1) * l.width + i1) * 3];
  for (int c = 0; c < 3; ++c) {
    const double top = t00[c] * (1 - ax) + t10[c] * ax;
    const double bottom = t01[c] * (1 - ax) + t11[c] * ax;
    out[c] = static_cast<float>(top * (1 - ay) + bottom * ay);
  }
}

void Texture::Sample(double u, double v, double footprint, float out[3]) const {
  const double lod = std::clamp(std::log2(std::max(footprint, 1.0)), 0.0, static_cast<double>(num_levels() - 1));
  const int l0 = static_cast<int>(std::floor(lod));
  const double t = lod - l0;
  const double s0 = std::ldexp(1.0, -l0);
  SampleLevel(l0, u * s0, v * s0, out);
  if (t > 0.0 && l0 + 1 < num_levels()) {
    float upper[3];
    SampleLevel(l0 + 1, u * s0 * 0.5, v * s0 * 0.5, upper);
    for (int c = 0; c < 3; ++c) out[c] = static_cast<float>((1 - t) * out[c] + t * upper[c]);
  }
}

Frame::Frame(int width, int height, const float background[3])
    : width_(width), height_(height) {
  M3C_CHECK(width > 0 && height > 0) << "image size must be positive, got " << width << " x " << height;
  const size_t n = static_cast<size_t>(width) * height;
  rgb_.resize(n * 3);
  for (size_t i = 0; i < n; ++i) std::copy(background, background + 3, &rgb_[i * 3]);
  depth_.assign(n, std::numeric_limits<float>::infinity());
  ids_.assign(n, -1);
}

Frame::~Frame() = default;

void Frame::Draw(const Intrinsics& K, double near, const double* vertices, int num_vertices, const int32_t* faces,
                 int num_faces, const Material& m) {
  M3C_CHECK(near > 0.0 && std::isfinite(near)) << "near must be a positive distance, got " << near;
  M3C_CHECK(m.ambient >= 0.0 && m.ambient <= 1.0) << "ambient must lie in [0, 1], got " << m.ambient;
  M3C_CHECK(K.fx > 0.0 && K.fy > 0.0) << "focal lengths must be positive, got " << K.fx << ", " << K.fy;
  M3C_CHECK((m.texture != nullptr) != (m.face_rgb != nullptr)) << "a material needs a texture or face colours";
  M3C_CHECK(m.texture == nullptr || m.uv != nullptr) << "a textured mesh needs uv coordinates";
  for (int f = 0; f < num_faces; ++f) {
    for (int k = 0; k < 3; ++k) {
      M3C_CHECK(faces[3 * f + k] >= 0 && faces[3 * f + k] < num_vertices)
          << "face " << f << " refers to vertex " << faces[3 * f + k] << ", outside [0, " << num_vertices << ")";
    }
  }

  const int shading = static_cast<int>(shadings_.size());
  shadings_.push_back({m.texture, m.light, m.ambient, m.id, m.normals != nullptr});
  intrinsics_.push_back(K);
  for (int f = 0; f < num_faces; ++f) {
    std::array<ClipVertex, 3> corner;
    bool finite = true;
    for (int k = 0; k < 3; ++k) {
      const int v = faces[3 * f + k];
      corner[k].p = Eigen::Vector3d(vertices[3 * v], vertices[3 * v + 1], vertices[3 * v + 2]);
      if (m.uv) corner[k].uv = Eigen::Vector2d(m.uv[2 * v], m.uv[2 * v + 1]);
      if (m.normals) corner[k].n = Eigen::Vector3d(m.normals[3 * v], m.normals[3 * v + 1], m.normals[3 * v + 2]);
      finite = finite && corner[k].p.allFinite();
    }
    if (!finite) continue;
    const Eigen::Vector3d face_normal = (corner[1].p - corner[0].p).cross(corner[2].p - corner[0].p);
    std::array<ClipVertex, 4> poly;
    const int count = ClipNear(corner, near, poly);
    for (int k = 1; k + 1 < count; ++k) {  // fan
      const std::array<const ClipVertex*, 3> c{&poly[0], &poly[k], &poly[k + 1]};
      ScreenTriangle t;
      for (int i = 0; i < 3; ++i) {
        const Eigen::Vector3d& p = c[i]->p;
        t.w[i] = 1.0 / p.z();
        t.s[i] = Eigen::Vector2d(K.fx * p.x() * t.w[i] + K.cx, K.fy * p.y() * t.w[i] + K.cy);
        t.uv_w[i] = c[i]->uv * t.w[i];
        t.n_w[i] = c[i]->n * t.w[i];
      }
      const Eigen::Vector2d e1 = t.s[1] - t.s[0], e2 = t.s[2] - t.s[0];
      const double area = e1.x() * e2.y() - e1.y() * e2.x();
      // A face whose right-hand normal points at the camera has a negative signed area in the image.
      if (area == 0.0 || !std::isfinite(area) || (m.cull && area > 0.0)) continue;
      const double xmin = std::min({t.s[0].x(), t.s[1].x(), t.s[2].x()});
      const double xmax = std::max({t.s[0].x(), t.s[1].x(), t.s[2].x()});
      const double ymin = std::min({t.s[0].y(), t.s[1].y(), t.s[2].y()});
      const double ymax = std::max({t.s[0].y(), t.s[1].y(), t.s[2].y()});
      if (xmax < 0 || ymax < 0 || xmin > width_ - 1 || ymin > height_ - 1) continue;
      t.x0 = std::max(0, static_cast<int>(std::ceil(xmin)));
      t.x1 = std::min(width_ - 1, static_cast<int>(std::floor(xmax)));
      t.y0 = std::max(0, static_cast<int>(std::ceil(ymin)));
      t.y1 = std::min(height_ - 1, static_cast<int>(std::floor(ymax)));
      if (t.x0 > t.x1 || t.y0 > t.y1) continue;
      t.face_normal = face_normal;
      t.albedo = {0.0f, 0.0f, 0.0f};
      if (m.face_rgb) std::copy(m.face_rgb + 3 * f, m.face_rgb + 3 * f + 3, t.albedo.begin());
      t.shading = shading;
      queued_.push_back(t);
    }
  }
}

void Frame::Resolve() {
  if (queued_.empty()) return;
  const std::vector<ScreenTriangle>& tris = queued_;
  // Bands of rows, one thread each at a time; every triangle is listed in the bands it touches (in drawing
  // order), so that a band reads only its own triangles.
  const int bands = std::min(height_, 32);
  std::vector<int> band_of_row(height_);
  for (int band = 0; band < bands; ++band) {
    for (int y = band * height_ / bands; y < (band + 1) * height_ / bands; ++y) band_of_row[y] = band;
  }
  std::vector<std::vector<int>> bins(bands);
  for (int i = 0; i < static_cast<int>(tris.size()); ++i) {
    for (int band = band_of_row[tris[i].y0]; band <= band_of_row[tris[i].y1]; ++band) bins[band].push_back(i);
  }
#pragma omp parallel for schedule(dynamic, 1)
  for (int band = 0; band < bands; ++band) {
    const int row0 = band * height_ / bands, row1 = (band + 1) * height_ / bands - 1;
    for (const int index : bins[band]) {
      const ScreenTriangle& t = tris[index];
      const Shading& m = shadings_[t.shading];
      const Intrinsics& K = intrinsics_[t.shading];
      // Edge functions made positive inside whatever the winding; edge k is opposite vertex k.
      const Eigen::Vector2d e1 = t.s[1] - t.s[0], e2 = t.s[2] - t.s[0];
      const double sign = (e1.x() * e2.y() - e1.y() * e2.x()) < 0 ? -1.0 : 1.0;
      std::array<double, 3> dx, dy;
      std::array<bool, 3> top_left;
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector2d& p = t.s[(k + 1) % 3];
        const Eigen::Vector2d& q = t.s[(k + 2) % 3];
        dx[k] = (q.x() - p.x()) * sign;
        dy[k] = (q.y() - p.y()) * sign;
        top_left[k] = dy[k] < 0 || (dy[k] == 0 && dx[k] > 0);
      }
      // Screen-space derivatives of the barycentrics (the edge functions are affine; they sum to a constant).
      // Their sum is edge 0's function at vertex 0 (the other two vanish there).
      const double total = dx[0] * (t.s[0].y() - t.s[1].y()) - dy[0] * (t.s[0].x() - t.s[1].x());
      std::array<double, 3> db_dx, db_dy;
      for (int k = 0; k < 3; ++k) {
        db_dx[k] = -dy[k] / total;
        db_dy[k] = dx[k] / total;
      }
      double dw_dx = 0, dw_dy = 0;
      Eigen::Vector2d duvw_dx = Eigen::Vector2d::Zero(), duvw_dy = Eigen::Vector2d::Zero();
      for (int k = 0; k < 3; ++k) {
        dw_dx += db_dx[k] * t.w[k];
        dw_dy += db_dy[k] * t.w[k];
        duvw_dx += db_dx[k] * t.uv_w[k];
        duvw_dy += db_dy[k] * t.uv_w[k];
      }
      const int y_start = std::max(t.y0, row0), y_stop = std::min(t.y1, row1);
      for (int py = y_start; py <= y_stop; ++py) {
        // The row's span: along a row each edge function is affine in px (slope -dy), so every edge bounds px on
        // one side; one pixel of slack each way, the exact test below decides.
        double lo = t.x0, hi = t.x1;
        for (int k = 0; k < 3; ++k) {
          const Eigen::Vector2d& p = t.s[(k + 1) % 3];
          const double at_zero = dx[k] * (py - p.y()) + dy[k] * p.x();  // e_k = at_zero - dy * px
          if (dy[k] > 0) {
            hi = std::min(hi, at_zero / dy[k] + 1.0);
          } else if (dy[k] < 0) {
            lo = std::max(lo, at_zero / dy[k] - 1.0);
          } else if (at_zero < 0) {
            hi = lo - 1.0;  // parallel edge with the row outside it
          }
        }
        const int x_start = std::max(t.x0, static_cast<int>(std::ceil(lo)));
        const int x_stop = std::min(t.x1, static_cast<int>(std::floor(hi)));
        for (int px = x_start; px <= x_stop; ++px) {
          std::array<double, 3> e;
          bool inside = true;
          for (int k = 0; k < 3; ++k) {
            const Eigen::Vector2d& p = t.s[(k + 1) % 3];
            e[k] = dx[k] * (py - p.y()) - dy[k] * (px - p.x());
            inside = inside && (e[k] > 0 || (e[k] == 0 && top_left[k]));
          }
          if (!inside) continue;
          const double sum = e[0] + e[1] + e[2];
          const double b0 = e[0] / sum, b1 = e[1] / sum, b2 = e[2] / sum;
          const double w = b0 * t.w[0] + b1 * t.w[1] + b2 * t.w[2];
          const double z = 1.0 / w;
          const size_t pixel = static_cast<size_t>(py) * width_ + px;
          if (!(z < depth_[pixel])) continue;
          float albedo[3];
          if (m.texture) {
            const Eigen::Vector2d uv_w = b0 * t.uv_w[0] + b1 * t.uv_w[1] + b2 * t.uv_w[2];
            const Eigen::Vector2d uv = uv_w * z;
            const Eigen::Vector2d du_dx = z * (duvw_dx - uv * dw_dx), du_dy = z * (duvw_dy - uv * dw_dy);
            m.texture->Sample(uv.x(), uv.y(), std::max(du_dx.norm(), du_dy.norm()), albedo);
          } else {
            std::copy(t.albedo.begin(), t.albedo.end(), albedo);
          }
          Eigen::Vector3d n = m.smooth ? Eigen::Vector3d((b0 * t.n_w[0] + b1 * t.n_w[1] + b2 * t.n_w[2]) * z)
                                        : t.face_normal;
          const Eigen::Vector3d position((px - K.cx) / K.fx * z, (py - K.cy) / K.fy * z, z);
          if (n.dot(position) > 0) n = -n;  // two-sided: the side facing the camera
          const double length = n.norm();
          const double diffuse = length > 0 ? std::max(0.0, n.dot(m.light) / length) : 0.0;
          const float shade = static_cast<float>(m.ambient + (1.0 - m.ambient) * diffuse);
          for (int c = 0; c < 3; ++c) rgb_[pixel * 3 + c] = std::min(1.0f, albedo[c] * shade);
          depth_[pixel] = static_cast<float>(z);
          ids_[pixel] = m.id;
        }
      }
    }
  }
  queued_.clear();
  shadings_.clear();
  intrinsics_.clear();
}

}  // namespace m3c::render
