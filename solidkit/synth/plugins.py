"""solidkit's Mitsuba plugins: OpenCV pinhole and conventions-equirect sensors, a buffers integrator.

Both sensors generate rays in *our* conventions (docs/conventions.md), so Mitsuba's own
camera conventions never enter solidkit:

- ``sk_pinhole``: intrinsics ``fx, fy, cx, cy`` (pixels, OpenCV: pixel ``(x, y)`` has its centre
  at ``(x, y)``); the camera-frame ray is ``((x - cx)/fx, (y - cy)/fy, 1)`` (x right, y down,
  z forward), normalised, then mapped by ``to_world``.
- ``sk_equirect``: the panorama mapping of conventions §3 (``phi = 2 pi (u + 0.5)/W - pi``,
  ``theta = pi/2 - pi (v + 0.5)/H``, ``d = (cos t sin p, -sin t, cos t cos p)``) in the sensor's
  local frame, mapped by ``to_world``. Pinned to :func:`solidkit.envmap.direction_from_coords`
  by ``tests/synth/test_conventions.py``.

With ``jitter = false`` a sensor shoots every sample through the pixel centre (geometry
buffers are then exact per pixel); otherwise uniformly within the pixel (box filter).

``sk_buffers`` returns, per camera ray, the AOVs :data:`BUFFER_AOVS`: hit distance ``t``,
camera-facing geometric normal (world), diffuse albedo (``BSDF.eval_diffuse_reflectance``),
the object label (mesh attribute ``face_label``; -1 = no hit), and the direct irradiance of a
white Lambertian surface from the scene's environment emitter (luminance), with and without
the visibility test (``shadow_on``/``shadow_off``): the paper's "render twice with shadows on and
off", estimated from the *same* directions (one emitter sample and one cosine sample per
pass, balance-heuristic MIS), so that their ratio is nearly noise free. Directions below the
horizon (``d_y > 0`` in the scene frame) are left out of both: the infinite ground plane hides
them everywhere, they are no one's cast shadow.
"""

from __future__ import annotations

from typing import Any

__all__ = ["BUFFER_AOVS", "register"]

BUFFER_AOVS = ("t", "nx", "ny", "nz", "albedo_r", "albedo_g", "albedo_b", "label", "shadow_on", "shadow_off")


def register(mi: Any) -> None:  # mitsuba: its classes depend on the variant set
    """Register ``sk_pinhole``, ``sk_equirect`` and ``sk_buffers`` for the active variant."""
    import drjit as dr

    class _Base(mi.Sensor):
        def __init__(self, props):
            super().__init__(props)
            self.jitter = bool(props.get("jitter", True))

        def _film_xy(self, sample2):
            size = self.film().size()
            x = sample2.x * float(size[0])
            y = sample2.y * float(size[1])
            if not self.jitter:
                x = dr.floor(x) + 0.5
                y = dr.floor(y) + 0.5
            return x, y, float(size[0]), float(size[1])

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            d = self._local_direction(sample2)
            tr = self.world_transform()
            ray = mi.Ray3f(tr @ mi.Point3f(0.0, 0.0, 0.0), dr.normalize(tr @ d), time, [])
            return ray, mi.Color3f(1.0)

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
            return mi.RayDifferential3f(ray), weight

        def traverse(self, callback):
            pass

    class PinholeSensor(_Base):
        def __init__(self, props):
            super().__init__(props)
            self.fx = float(props["fx"])
            self.fy = float(props["fy"])
            self.cx = float(props["cx"])
            self.cy = float(props["cy"])

        def _local_direction(self, sample2):
            x, y, _, _ = self._film_xy(sample2)
            # film coordinate x covers pixel x - 0.5 .. x + 0.5 in OpenCV's convention
            vx = (x - 0.5 - self.cx) / self.fx
            vy = (y - 0.5 - self.cy) / self.fy
            return dr.normalize(mi.Vector3f(vx, vy, 1.0))

        def to_string(self):
            return f"PinholeSensor[fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy}]"

    class EquirectSensor(_Base):
        def _local_direction(self, sample2):
            x, y, w, h = self._film_xy(sample2)
            phi = x * (2.0 * dr.pi / w) - dr.pi
            theta = 0.5 * dr.pi - y * (dr.pi / h)
            ct = dr.cos(theta)
            return mi.Vector3f(ct * dr.sin(phi), -dr.sin(theta), ct * dr.cos(phi))

        def to_string(self):
            return "EquirectSensor[]"

    class BuffersIntegrator(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.shadows = bool(props.get("shadows", True))

        def sample(self, scene, sampler, ray, medium=None, active=True):
            si = scene.ray_intersect(mi.Ray3f(ray), active)
            valid = si.is_valid()
            if isinstance(valid, bool) and not valid:  # scalar variants: no shape/BSDF to query
                return mi.Color3f(0.0), False, [0.0] * 7 + [-1.0, 0.0, 0.0]
            n = mi.Vector3f(si.n)
            n = dr.select(dr.dot(n, ray.d) > 0, -n, n)
            bsdf = si.bsdf()
            albedo = dr.select(valid, bsdf.eval_diffuse_reflectance(si, valid), 0.0)
            label = dr.select(valid, si.shape.eval_attribute_1("face_label", si, valid), -1.0)
            t = dr.select(valid, si.t, 0.0)
            env = scene.environment()
            if not self.shadows or env is None:
                return mi.Color3f(0.0), valid, [t, n.x, n.y, n.z, albedo.x, albedo.y, albedo.z, label, 0.0 * t, 0.0 * t]
            # irradiance of a white Lambertian surface from the environment, above the horizon
            # (the infinite ground blocks the rest), with and without shadow rays: one emitter
            # sample and one cosine sample combined by the balance heuristic (MIS)
            ds, _ = env.sample_direction(si, sampler.next_2d(valid), valid)
            frame = mi.Frame3f(n)
            d_c = frame.to_world(mi.warp.square_to_cosine_hemisphere(sampler.next_2d(valid)))
            off, on = mi.Float(0.0), mi.Float(0.0)
            jit = dr.is_jit_v(mi.Float)
            for d in (ds.d, d_c):
                cos = dr.maximum(dr.dot(n, d), 0.0)
                si_e = dr.zeros(mi.SurfaceInteraction3f)
                si_e.wi = -d
                radiance = mi.luminance(env.eval(si_e, valid))
                ds_q = dr.zeros(mi.DirectionSample3f) if jit else mi.DirectionSample3f()
                ds_q.d = d
                p_e = env.pdf_direction(si, ds_q, valid)
                p_c = cos / dr.pi
                ok = valid & (cos > 0) & (d.y < 0) & (p_e + p_c > 0)
                c = dr.select(ok, radiance * cos / dr.maximum(p_e + p_c, 1e-20), 0.0)
                occluded = scene.ray_test(si.spawn_ray(d), ok)
                off = off + c
                on = on + dr.select(occluded, 0.0, c)
            aovs = [t, n.x, n.y, n.z, albedo.x, albedo.y, albedo.z, label, on, off]
            return mi.Color3f(0.0), valid, aovs

        def aov_names(self):
            return list(BUFFER_AOVS)

        def to_string(self):
            return "BuffersIntegrator[]"

    mi.register_sensor("sk_pinhole", lambda props: PinholeSensor(props))
    mi.register_sensor("sk_equirect", lambda props: EquirectSensor(props))
    mi.register_integrator("sk_buffers", lambda props: BuffersIntegrator(props))
