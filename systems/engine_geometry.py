"""``EngineGeometry``: the quasi-static engine's chain (and the heart's wall, targets and the
sheath) drawn through a SceneGraph of its own. ``quasi_static_engine`` re-exports it.
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    FramePoseVector,
    GeometryFrame,
    GeometryInstance,
    IllustrationProperties,
    Mesh,
    Rgba,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import LeafSystem

from ballchain.drake_models.field_sources import rotation_with_z_along
from ballchain.optimization.wall_constraints import SheathGeometry
from ballchain.systems.meshcat_view import TARGET_CENTRE_RADIUS, TARGET_CENTRE_RGBA


class EngineGeometry(LeafSystem):
    """Draws the engine's chain (and the heart's wall, targets and the sheath) through a SceneGraph.

    Registers itself as a geometry source with illustration geometry only: the balls (grey,
    with a red marker along the dipole) on frames posed from ``body_poses``, and anchored
    geometry for the wall mesh (OBJ), the ablation targets and the sheath. A MeshcatVisualizer
    on the same SceneGraph draws and records them, as it does the plant's.

    Input ports:
        body_poses: abstract list[RigidTransform] (the engine's).

    Output ports:
        geometry_pose: FramePoseVector (connect to the SceneGraph's source pose port).

    With ``moving_anatomy`` the wall and the targets sit on a frame ``heart`` and the sheath on
    a frame ``sheath``, posed from the input port ``anatomy_offsets`` (6: the heart's and the
    wall's offsets [m], the engine's port of that name), so that the recording moves them with
    the chain's solves.
    """

    def __init__(self, scene_graph, ball_body_indices, ball_radius: float, heart=None, sheath: SheathGeometry | None = None,
                 sheath_length: float = 0.0, moving_anatomy: bool = False):
        super().__init__()
        self._indices = [int(i) for i in ball_body_indices]
        self.source_id = scene_graph.RegisterSource("quasi_static_engine")
        self._frames = []
        colors = [Rgba(0.75, 0.75, 0.78, 1.0), Rgba(0.45, 0.45, 0.5, 1.0)]

        def add(frame_id, X, shape, name, rgba):
            g = scene_graph.RegisterGeometry(self.source_id, frame_id, GeometryInstance(X, shape, name))
            props = IllustrationProperties()
            props.AddProperty("phong", "diffuse", rgba)
            scene_graph.AssignRole(self.source_id, g, props)

        for i in range(len(self._indices)):
            f = scene_graph.RegisterFrame(self.source_id, GeometryFrame(f"ball_{i + 1}"))
            self._frames.append(f)
            add(f, RigidTransform(), Sphere(ball_radius), f"ball_{i + 1}", colors[i % 2])
            add(f, RigidTransform([0.6 * ball_radius, 0, 0]), Sphere(0.45 * ball_radius), f"ball_{i + 1}_north",
                Rgba(0.8, 0.1, 0.1, 1.0))
        world = wall_frame = sheath_frame = scene_graph.world_frame_id()
        if moving_anatomy:  # frames that move with the anatomy (else anchored, as without motion)
            wall_frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame("heart"))
            sheath_frame = scene_graph.RegisterFrame(self.source_id, GeometryFrame("sheath"))
        self._anatomy_frames = (wall_frame, sheath_frame)
        if heart is not None:
            files = heart.write_files()
            add(wall_frame, RigidTransform(), Mesh(str(files["obj"])), "heart_wall", Rgba(0.85, 0.35, 0.35, 0.35))
            for side, ring in heart.rings.items():
                for k, p in enumerate(ring.p_HT):
                    add(wall_frame, RigidTransform(p), Sphere(TARGET_CENTRE_RADIUS), f"target_{side}_{k + 1}",
                        Rgba(*TARGET_CENTRE_RGBA))
        if sheath is not None and sheath_length > 0:
            from pydrake.geometry import Cylinder

            R = RotationMatrix(rotation_with_z_along(sheath.axis_W))
            centre = sheath.p_WE - 0.5 * sheath_length * sheath.axis_W
            add(sheath_frame, RigidTransform(R, centre),
                Cylinder(sheath.bore_radius + 2 * sheath.lip_radius, sheath_length), "sheath", Rgba(0.3, 0.5, 0.9, 0.3))
        self._poses_port = self.DeclareAbstractInputPort("body_poses", AbstractValue.Make([RigidTransform()]))
        self._anatomy_port = self.DeclareVectorInputPort("anatomy_offsets", 6) if moving_anatomy else None
        self._pose_output = self.DeclareAbstractOutputPort(
            "geometry_pose", lambda: AbstractValue.Make(FramePoseVector()), self._calc_geometry_pose)

    def get_body_poses_input_port(self):
        return self._poses_port

    def get_geometry_pose_output_port(self):
        return self._pose_output

    def get_anatomy_offsets_input_port(self):
        return self._anatomy_port

    def _calc_geometry_pose(self, context, output):
        poses = self._poses_port.Eval(context)
        value = output.get_mutable_value()  # the same frames every time: overwritten, not cleared
        for frame, index in zip(self._frames, self._indices):
            value.set_value(frame, poses[index])
        if self._anatomy_port is not None:
            offsets = self._anatomy_port.Eval(context)
            value.set_value(self._anatomy_frames[0], RigidTransform(offsets[3:]))
            value.set_value(self._anatomy_frames[1], RigidTransform(offsets[:3]))
