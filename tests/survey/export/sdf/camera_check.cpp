// Load a world with the real SDFormat library (libsdformat-dev) and print, as key=value
// lines the tests read back, what libsdformat parsed of every camera sensor, every
// light inside a link, and every model frame (poses resolved in the model's frame).
// Usage: camera_check WORLD.sdf MODELS_DIR   (model://NAME resolves to MODELS_DIR/NAME)
// Exit status: 0 clean, 1 parser errors (warnings and unknown elements count), 2 usage.
#include <sdf/sdf.hh>

#include <iostream>
#include <string>

static void printPose(const ignition::math::Pose3d &p) {
  std::cout << " x=" << p.Pos().X() << " y=" << p.Pos().Y() << " z=" << p.Pos().Z()
            << " qw=" << p.Rot().W() << " qx=" << p.Rot().X() << " qy=" << p.Rot().Y()
            << " qz=" << p.Rot().Z();
}

int main(int argc, char **argv) {
  if (argc != 3) {
    std::cerr << "usage: camera_check WORLD.sdf MODELS_DIR\n";
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
  std::cout.precision(17);
  int bad = 0;
  for (uint64_t w = 0; w < root.WorldCount(); ++w) {
    const sdf::World *world = root.WorldByIndex(w);
    for (uint64_t m = 0; m < world->ModelCount(); ++m) {
      const sdf::Model *model = world->ModelByIndex(m);
      for (uint64_t f = 0; f < model->FrameCount(); ++f) {
        const sdf::Frame *frame = model->FrameByIndex(f);
        ignition::math::Pose3d pose;
        const sdf::Errors perr = frame->SemanticPose().Resolve(pose, "__model__");
        bad += static_cast<int>(perr.size());
        std::cout << "frame name=" << frame->Name() << " attached_to="
                  << frame->AttachedTo();
        printPose(pose);
        std::cout << "\n";
      }
      for (uint64_t l = 0; l < model->LinkCount(); ++l) {
        const sdf::Link *link = model->LinkByIndex(l);
        for (uint64_t i = 0; i < link->LightCount(); ++i) {
          const sdf::Light *light = link->LightByIndex(i);
          ignition::math::Pose3d pose;
          const sdf::Errors perr = light->SemanticPose().Resolve(pose, "__model__");
          bad += static_cast<int>(perr.size());
          const auto d = light->Direction();
          std::cout << "light name=" << light->Name() << " link=" << link->Name()
                    << " type=" << static_cast<int>(light->Type())
                    << " intensity=" << light->Intensity()
                    << " range=" << light->AttenuationRange()
                    << " constant=" << light->ConstantAttenuationFactor()
                    << " linear=" << light->LinearAttenuationFactor()
                    << " quadratic=" << light->QuadraticAttenuationFactor()
                    << " dx=" << d.X() << " dy=" << d.Y() << " dz=" << d.Z()
                    << " inner=" << light->SpotInnerAngle().Radian()
                    << " outer=" << light->SpotOuterAngle().Radian()
                    << " falloff=" << light->SpotFalloff();
          printPose(pose);
          std::cout << "\n";
        }
        for (uint64_t s = 0; s < link->SensorCount(); ++s) {
          const sdf::Sensor *sen = link->SensorByIndex(s);
          const sdf::Camera *cam = sen->CameraSensor();
          if (!cam) continue;
          ignition::math::Pose3d pose;
          const sdf::Errors perr = sen->SemanticPose().Resolve(pose, "__model__");
          bad += static_cast<int>(perr.size());
          std::cout << "camera name=" << sen->Name() << " type=" << sen->TypeStr()
                    << " topic=" << sen->Topic() << " update_rate=" << sen->UpdateRate()
                    << " hfov=" << cam->HorizontalFov().Radian()
                    << " width=" << cam->ImageWidth() << " height=" << cam->ImageHeight()
                    << " format=" << cam->PixelFormatStr()
                    << " near=" << cam->NearClip() << " far=" << cam->FarClip()
                    << " depth_near=" << cam->DepthNearClip()
                    << " depth_far=" << cam->DepthFarClip()
                    << " k1=" << cam->DistortionK1() << " k2=" << cam->DistortionK2()
                    << " k3=" << cam->DistortionK3() << " p1=" << cam->DistortionP1()
                    << " p2=" << cam->DistortionP2()
                    << " center_x=" << cam->DistortionCenter().X()
                    << " center_y=" << cam->DistortionCenter().Y()
                    << " lens=" << cam->LensType()
                    << " scale_to_hfov=" << cam->LensScaleToHfov()
                    << " cutoff=" << cam->LensCutoffAngle().Radian()
                    << " fx=" << cam->LensIntrinsicsFx() << " fy=" << cam->LensIntrinsicsFy()
                    << " cx=" << cam->LensIntrinsicsCx() << " cy=" << cam->LensIntrinsicsCy()
                    << " s=" << cam->LensIntrinsicsSkew();
          printPose(pose);
          std::cout << "\n";
        }
      }
    }
  }
  return bad ? 1 : 0;
}
