"""SKYLOC_OT_render_database: a skyline database around the site, locally or on the render service.

Locally it runs ``skyloc db render`` in a subprocess (the add-on never imports the service);
with "Use render service" it uploads the DEM and submits a job over HTTP.  Either way a timer
polls the work and updates the panel's progress bar, unless ``wait`` is set (headless use), in
which case the operator returns when the database is finished.
"""
from __future__ import annotations

import logging
import subprocess
import time

import bpy  # noqa: TID251 (extension layer)
from bpy.props import BoolProperty

from .. import bridge

log = logging.getLogger(__name__)


def _local_fraction(store) -> float:
    from board.skydb import SkyDB

    try:
        db = SkyDB.open(store)
        m = db.done_mask()
        return float(m.mean()) if m.size else 0.0
    except Exception:  # noqa: BLE001 (the store may not exist yet)
        return 0.0


class SKYLOC_OT_render_database(bpy.types.Operator):
    """Render the skyline database of a grid around the site (locally, or on the render service)"""

    bl_idname = "skyloc.render_database"
    bl_label = "Render database"
    bl_options = {"REGISTER"}

    wait: BoolProperty(name="Wait", description="Block until the database is finished (headless use)",
                       default=False, options={"SKIP_SAVE"})

    def execute(self, context):
        s = bridge.settings(context)
        try:
            if s.use_service:
                poll = self._submit_service(s)
            else:
                poll = self._start_local(s)
        except Exception as exc:  # noqa: BLE001 (reported to the user)
            return bridge.fail(self, "Render database", exc)
        s.busy, s.progress = True, 0.0
        if self.wait:
            while (interval := poll()) is not None:
                time.sleep(interval)
            if s.status.startswith("database failed"):
                self.report({"ERROR"}, s.status)
                return {"CANCELLED"}
        else:
            bpy.app.timers.register(poll, first_interval=0.5)
        self.report({"INFO"}, s.status)
        return {"FINISHED"}

    def _start_local(self, s):
        dem = bridge.dem_path(s)
        store = bridge.out_dir(s) / "skyline_db.zarr"
        store.parent.mkdir(parents=True, exist_ok=True)
        cmd = [*bridge.skyloc_command(), "db", "render", "--dem", str(dem), "--center", f"{s.site_x},{s.site_y}",
               "--size", str(s.db_size_m), "--step", str(s.db_step_m), "--height", str(s.mast_height_m),
               "--renderer", s.renderer, "--out", str(store), "--no-progress"]
        if bridge.body_arg(s):
            cmd += ["--body", bridge.body_arg(s)]
        log.info("running %s", " ".join(cmd))
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                env=bridge.env_for_subprocess())
        s.status = f"rendering {store.name} locally ({s.renderer})"

        def poll():
            code = proc.poll()
            s.progress = _local_fraction(store) if code is None else (1.0 if code == 0 else s.progress)
            if code is None:
                return 1.0
            out = proc.stdout.read() if proc.stdout else ""
            s.busy = False
            s.status = (f"database written to {store}" if code == 0
                        else f"database failed (exit {code}): {out.strip().splitlines()[-1] if out.strip() else ''}")
            return None

        return poll

    def _submit_service(self, s):
        from blender_addon.core import service_client as sc

        url, token = s.service_url, s.service_token or None
        dem = sc.upload_dem(url, bridge.dem_path(s), body=bridge.body_arg(s), token=token)
        job = sc.submit_db_job(url, dem_id=dem["id"], center=(s.site_x, s.site_y), size_m=s.db_size_m,
                               step_m=s.db_step_m, camera_height_m=s.mast_height_m, renderer=s.renderer,
                               token=token)
        s.status = f"service job {job['id']}: {job.get('state')}"

        def poll():
            try:
                j = sc.job_status(url, job["id"], token=token)
            except sc.ServiceError as exc:
                s.busy, s.status = False, f"database failed: {exc}"
                return None
            s.progress = sc.job_fraction(j)
            done, total = j.get("tiles_done", 0), j.get("tiles_total", "?")
            s.status = f"service job {j['id']}: {j.get('state')} ({done}/{total} tiles)"
            if j.get("state") in ("done", "failed", "cancelled"):
                s.busy = False
                if j.get("state") != "done":
                    s.status = f"database failed on the service: {j.get('error') or j.get('state')}"
                return None
            return 1.0

        return poll
