// Load a world with the real SDFormat library (libsdformat-dev) and report:
//   - every parser error (warnings and unrecognised elements count as errors),
//   - each mesh URI and whether it resolves to an existing file,
//   - each lidar sensor's parameters as key=value lines (read back by the tests),
//   - each sensor's pose in its model's frame (sensor_pose name=... x y z qw qx qy qz).
// Usage: sdf_check WORLD.sdf MODELS_DIR   (model://NAME resolves to MODELS_DIR/NAME)
// Exit status: 0 clean, 1 errors or a missing mesh, 2 usage.
#include <sdf/sdf.hh>

#include <filesystem>
#include <iostream>
#include <string>

namespace fs = std::filesystem;

static std::string resolve(const std::string &uri, const std::string &models,
                           const std::string &base) {
  const std::string scheme = "model://";
  if (uri.rfind(scheme, 0) == 0) return models + "/" + uri.substr(scheme.size());
  if (uri.rfind("file://", 0) == 0) return uri.substr(7);
  if (!uri.empty() && uri[0] == '/') return uri;
  return base + "/" + uri;
}

static int checkGeometry(const sdf::Geometry *g, const std::string &what,
                         const std::string &models, const std::string &base) {
  if (!g || g->Type() != sdf::GeometryType::MESH || !g->MeshShape()) return 0;
  const std::string uri = g->MeshShape()->Uri();
  const std::string path = resolve(uri, models, base);
  const bool ok = fs::is_regular_file(path) && fs::file_size(path) > 0;
  std::cout << "mesh " << what << " " << uri << " -> " << (ok ? "ok" : "MISSING") << "\n";
  return ok ? 0 : 1;
}

int main(int argc, char **argv) {
  if (argc != 3) {
    std::cerr << "usage: sdf_check WORLD.sdf MODELS_DIR\n";
    return 2;
  }
  sdf::ParserConfig cfg;
  cfg.AddURIPath("model://", argv[2]);
  cfg.SetWarningsPolicy(sdf::EnforcementPolicy::ERR);
  cfg.SetUnrecognizedElementsPolicy(sdf::EnforcementPolicy::ERR);
  sdf::Root root;
  const sdf::Errors errs = root.Load(argv[1], cfg);
  for (const auto &e : errs) std::cout << "error " << e.Message() << "\n";
  if (!errs.empty()) return 1;
  int bad = 0;
  std::cout << "version " << root.Version() << "\n";
  for (uint64_t w = 0; w < root.WorldCount(); ++w) {
    const sdf::World *world = root.WorldByIndex(w);
    std::cout << "world " << world->Name() << " models " << world->ModelCount()
              << " lights " << world->LightCount() << "\n";
    for (uint64_t m = 0; m < world->ModelCount(); ++m) {
      const sdf::Model *model = world->ModelByIndex(m);
      std::cout << "model " << model->Name() << " static " << model->Static() << "\n";
      for (uint64_t l = 0; l < model->LinkCount(); ++l) {
        const sdf::Link *link = model->LinkByIndex(l);
        const std::string base = fs::path(link->Element()->FilePath()).parent_path();
        for (uint64_t v = 0; v < link->VisualCount(); ++v)
          bad += checkGeometry(link->VisualByIndex(v)->Geom(), "visual", argv[2], base);
        for (uint64_t c = 0; c < link->CollisionCount(); ++c)
          bad += checkGeometry(link->CollisionByIndex(c)->Geom(), "collision", argv[2], base);
        for (uint64_t s = 0; s < link->SensorCount(); ++s) {
          const sdf::Sensor *sen = link->SensorByIndex(s);
          // The sensor's pose resolved by libsdformat in the model frame (issue 30:
          // the tests compare it with robot.urdf's base_link -> sensor).
          ignition::math::Pose3d pose;
          const sdf::Errors perr = sen->SemanticPose().Resolve(pose, "__model__");
          bad += static_cast<int>(perr.size());
          for (const auto &e : perr) std::cout << "error " << e.Message() << "\n";
          std::cout.precision(17);
          std::cout << "sensor_pose name=" << sen->Name() << " x=" << pose.Pos().X()
                    << " y=" << pose.Pos().Y() << " z=" << pose.Pos().Z()
                    << " qw=" << pose.Rot().W() << " qx=" << pose.Rot().X()
                    << " qy=" << pose.Rot().Y() << " qz=" << pose.Rot().Z() << "\n";
          if (sen->Type() != sdf::SensorType::GPU_LIDAR &&
              sen->Type() != sdf::SensorType::LIDAR) continue;
          const sdf::Lidar *li = sen->LidarSensor();
          std::cout.precision(17);
          std::cout << "lidar name=" << sen->Name() << " topic=" << sen->Topic()
                    << " update_rate=" << sen->UpdateRate()
                    << " h_samples=" << li->HorizontalScanSamples()
                    << " h_min=" << li->HorizontalScanMinAngle().Radian()
                    << " h_max=" << li->HorizontalScanMaxAngle().Radian()
                    << " v_samples=" << li->VerticalScanSamples()
                    << " v_min=" << li->VerticalScanMinAngle().Radian()
                    << " v_max=" << li->VerticalScanMaxAngle().Radian()
                    << " range_min=" << li->RangeMin() << " range_max=" << li->RangeMax()
                    << " range_resolution=" << li->RangeResolution()
                    << " noise_stddev=" << li->LidarNoise().StdDev() << "\n";
        }
      }
    }
  }
  return bad ? 1 : 0;
}
