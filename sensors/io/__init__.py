"""sensors.io: the file-format layer, below the rest of ``sensors`` and all of ``survey``.

Every reader and writer of a file format lives here, and nothing here knows about
scanners, trajectories or tunnels (it imports only ``raytrace`` and itself). The
simulation's own outputs, which need the sensor model, sit one layer up and write through
this one: ``sensors.writers`` (``open_writer``: one streaming writer per suffix),
``sensors.bag`` (a simulated robot's ROS 2 bag: clouds, IMU, odometry, TF) and
``sensors.pointcloud2`` (each driver's PointCloud2 layout).

==================  ===================================================================
``las``             LAS 1.0-1.4 / LAZ, every point format, streamed; extra bytes; CRS VLRs
``copc``            Cloud Optimized Point Cloud writer (LAS 1.4 + hierarchy)
``ply``             binary/ASCII PLY headers, reader, streaming writer
``e57``             ASTM E57 scans (through the optional ``pye57``)
``crs``             coordinate reference systems: parsing, WKT VLRs, ``.prj`` sidecars
``fields``          the simulated point record (dtype, flags) and its names per format
``stream``          atomic (temporary name + rename) streams, background writing
``meshes``          ``read_mesh``/``load_mesh``: the one mesh loader
``tables``          control-point and trajectory tables: dialect sniffing
``cloudread``       any point cloud in, chunk by chunk (``iter_points``, ``read_points``)
``cloudmap``        a point cloud rewritten keeping every field (``map_cloud``)
``cloudfields``     one named field of any point cloud, chunk by chunk
``errors``          one error class per kind of file problem
==================  ===================================================================
"""

__all__: list[str] = []   # a namespace of modules: import ``sensors.io.las`` etc. by name
