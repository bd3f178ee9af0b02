"""Camera frames in a ROS 2 bag (``sensors.bag.RosbagStream.write_image``) and in a
frame folder (``sensors.camera_io.FrameFolder``), read back by third-party readers
(rosbags, Pillow): encodings and byte order, topics and frames of the drivers' naming,
the log order, and the refusals."""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sensors.bag import RosbagStream, camera_topics
from sensors.camera import load_camera
from sensors.camera_io import FrameFolder
from sensors.errors import SimulationError
from sensors.io.errors import PointFileError
from sensors.render import Frame
from sensors.spec import load_sensor
from sensors.trajectory import Mount, Trajectory

rosbags = pytest.importorskip("rosbags", reason="rosbags is in the test extra")
from rosbags.highlevel import AnyReader  # noqa: E402


def _small(name: str, w: int = 8, h: int = 6):
    return replace(load_camera(name), width=w, height=h, cx=(w - 1) / 2, cy=(h - 1) / 2)


def _stream(path, cameras):
    traj = Trajectory([0.0, 1.0], [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]], Rotation.identity(2))
    return RosbagStream(path, load_sensor("velodyne_vlp16"), single_file=True,
                        trajectory=traj, span_s=(0.0, 1.0), cameras=cameras)


def test_topics_follow_the_drivers():
    tc = camera_topics(load_camera("realsense_d435_color"))
    assert (tc.image, tc.info, tc.frame_id, tc.link, tc.encoding) == (
        "/camera/color/image_raw", "/camera/color/camera_info",
        "camera_color_optical_frame", "camera_link", "rgb8")
    td = camera_topics(load_camera("realsense_d435_depth"))
    assert (td.image, td.frame_id, td.encoding) == (
        "/camera/depth/image_rect_raw", "camera_depth_optical_frame", "16UC1")
    tt = camera_topics(load_camera("lwir_640"))
    assert (tt.image, tt.info, tt.frame_id, tt.link, tt.encoding) == (
        "/lwir_640/image_raw", "/lwir_640/camera_info", "lwir_640_optical_frame",
        "lwir_640_link", "mono16")


def test_thermal_image_round_trips_in_time_order(tmp_path):
    """A mono16 image (little-endian, step 2 w) decodes to the counts written; its log
    time sits among the poses and IMU samples; CameraInfo is stamped as the image."""
    cam = _small("lwir_640")
    counts = np.arange(48, dtype=np.uint16).reshape(6, 8) * 1000 + 7
    with _stream(tmp_path / "b.mcap", [(cam, Mount((0.1, 0.0, 0.2)))]) as w:
        w.write_image(0, 0.25, 0.2537, counts)
        w.write_image(0, 0.5, 0.5037, counts[::-1].copy())
        # Queued, not yet written: no time spent on them yet (a lidar's clock running
        # while the bag writes them later takes ``image_seconds`` out).
        assert w.image_seconds == [0.0]
    assert w.image_seconds[0] > 0.0 and w.messages["/lwir_640/image_raw"] == 2
    with AnyReader([tmp_path / "b.mcap"]) as r:
        logs = [(t, c.topic, r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages()]
    images = [(t, m) for t, tp, m in logs if tp == "/lwir_640/image_raw"]
    infos = [m for _t, tp, m in logs if tp == "/lwir_640/camera_info"]
    assert [t for t, _ in images] == [253_700_000, 503_700_000]
    t, m = images[0]
    assert (m.encoding, m.step, m.is_bigendian, m.height, m.width) == ("mono16", 16, 0, 6, 8)
    np.testing.assert_array_equal(np.frombuffer(m.data, "<u2").reshape(6, 8), counts)
    np.testing.assert_array_equal(
        np.frombuffer(images[1][1].data, "<u2").reshape(6, 8), counts[::-1])
    assert m.header.stamp.nanosec == 250_000_000 and m.header.frame_id == \
        "lwir_640_optical_frame"
    assert infos[0].header.stamp == m.header.stamp and len(infos) == 2
    order = [t for t, _tp, _m in logs]
    assert order == sorted(order)
    # IMU samples both before and after the first image.
    imu = [t for t, tp, _m in logs if tp == "/imu/data_raw"]
    assert min(imu) < images[0][0] < max(imu)


@pytest.mark.parametrize("image, match", [
    (np.zeros((6, 8), np.uint8), "mono16 image of shape"),
    (np.zeros((8, 6), np.uint16), r"\(6, 8\)"),
])
def test_a_wrong_image_is_refused(tmp_path, image, match):
    cam = _small("lwir_640")
    w = _stream(tmp_path / "b.mcap", [(cam, Mount())])
    with pytest.raises(PointFileError, match=match):
        w.write_image(0, 0.1, 0.11, image)
    w.abort()
    assert not (tmp_path / "b.mcap").exists()


def test_frames_out_of_order_or_outside_the_drive_are_refused(tmp_path):
    cam = _small("lwir_640")
    img = np.zeros((6, 8), np.uint16)
    w = _stream(tmp_path / "b.mcap", [(cam, Mount())])
    with pytest.raises(PointFileError, match="within the drive"):
        w.write_image(0, 0.99, 1.5, img)
    with pytest.raises(PointFileError, match="camera index below 1"):
        w.write_image(1, 0.1, 0.11, img)
    w.abort()


def test_two_cameras_on_one_topic_or_one_link_at_two_places_are_refused(tmp_path):
    c = load_camera("realsense_d435_color")
    d = load_camera("realsense_d435_depth")
    with pytest.raises(PointFileError, match="each camera on its own topic"):
        _stream(tmp_path / "a.mcap", [(c, Mount()), (c, Mount())])
    with pytest.raises(PointFileError, match="one place for camera_link"):
        _stream(tmp_path / "b.mcap", [(c, Mount()), (d, Mount((0.0, 0.05, 0.0)))])
    assert not list(tmp_path.iterdir())


def _frame(h=6, w=8, depth=1.5):
    z = np.full((h, w), depth)
    z[0, 0] = np.nan
    return Frame(np.isfinite(z), np.isfinite(z), z, z, np.zeros((h, w), np.int64),
                 np.zeros((h, w, 3)), np.zeros((h, w, 3)), np.zeros((h, w, 3)), np.eye(4),
                 np.zeros((h, w)), np.zeros((h, w)))


def test_frame_folder_writes_pngs_and_leaves_nothing_on_error(tmp_path):
    from PIL import Image

    cam = _small("realsense_d435_color")
    folder = tmp_path / "d_cameras" / cam.name
    with FrameFolder(folder, cam, np.eye(4)) as w:
        w.write(0, 1_000, _frame(), readout_end_s=0.01, time_s=1e-6,
                rgb_linear=np.full((6, 8, 3), 0.5))
    rgb = np.asarray(Image.open(io.BytesIO((folder / "rgb" / "000000_1000.png")
                                           .read_bytes())))
    assert rgb.shape == (6, 8, 3) and rgb.dtype == np.uint8
    assert int(rgb[0, 0, 0]) == 188               # sRGB of 0.5 (IEC 61966-2-1)
    depth = np.asarray(Image.open(folder / "depth" / "000000_1000.png"))
    assert depth[0, 0] == 0 and depth[1, 1] == 1500
    lines = (folder / "frames.csv").read_text().splitlines()
    assert lines[0].startswith("index,stamp_ns,time_s") and lines[1].startswith("0,1000,")
    # An error inside the block: no folder, no temporary one, no empty parent.
    other = tmp_path / "e_cameras" / cam.name
    with pytest.raises(RuntimeError):
        with FrameFolder(other, cam, np.eye(4)) as w:
            w.write(0, 0, _frame(), readout_end_s=0.01, time_s=0.0,
                    rgb_linear=np.zeros((6, 8, 3)))
            raise RuntimeError("stop")
    assert not (tmp_path / "e_cameras").exists()
    with pytest.raises(SimulationError, match="frame of 8x6 pixels"):
        with FrameFolder(other, cam, np.eye(4)) as w:
            w.write(0, 0, _frame(h=5), readout_end_s=0.01, time_s=0.0)
