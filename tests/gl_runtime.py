"""Exported GLSL run for real: a headless OpenGL 4.5 context on Mesa's llvmpipe (EGL, through
moderngl) and Khronos' reference compiler (``glslangValidator``). Tests skip with the reason when
either is missing (the Makefile installs them as root)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

HARNESS = """#version 450
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Wi {{ vec4 wi[]; }};
layout(std430, binding = 1) readonly buffer Wo {{ vec4 wo[]; }};
layout(std430, binding = 2) writeonly buffer Fr {{ vec4 fr[]; }};
uniform uint n;

{source}

void main() {{
    uint i = gl_GlobalInvocationID.x;
    if (i < n) fr[i] = vec4({call}(wi[i].xyz, wo[i].xyz), 0.0);
}}
"""


def gl_context():
    """A standalone EGL context, or skip naming what is missing."""
    try:
        import moderngl
    except ImportError:
        pytest.skip("moderngl is not installed (pip install 'neuenh[export]')")
    try:
        ctx = moderngl.create_context(standalone=True, backend="egl", require=450)
    except Exception as exc:  # noqa: BLE001 - any failure to get a GL 4.5 context is a reason to skip
        pytest.skip(f"no headless OpenGL 4.5 through EGL here ({exc}); install Mesa's libegl-mesa0 and "
                    "libgl1-mesa-dri (make gl)")
    return ctx


def run_brdf(ctx, source: str, wi: np.ndarray, wo: np.ndarray, call: str = "neuenh_brdf") -> np.ndarray:
    """``call(wi, wo)`` of ``source`` for every row, on the GPU context (float32, (n, 3))."""
    n = len(wi)
    program = ctx.compute_shader(HARNESS.format(source=source, call=call))
    pad = lambda w: np.hstack([w, np.zeros((n, 1))]).astype(np.float32)  # noqa: E731  (std430 vec4)
    buffers = [ctx.buffer(pad(wi).tobytes()), ctx.buffer(pad(wo).tobytes()), ctx.buffer(reserve=16 * n)]
    try:
        for binding, buffer in enumerate(buffers):
            buffer.bind_to_storage_buffer(binding)
        program["n"] = n
        program.run(group_x=(n + 63) // 64)
        return np.frombuffer(buffers[2].read(), dtype=np.float32).reshape(n, 4)[:, :3].copy()
    finally:
        for buffer in buffers:
            buffer.release()
        program.release()


def validate(source: str, where: Path, call: str = "neuenh_brdf") -> None:
    """Compile ``source`` in the harness with glslangValidator (Khronos' reference front end)."""
    validator = shutil.which("glslangValidator")
    if validator is None:
        pytest.skip("glslangValidator is not installed (Debian's glslang-tools; make glslang)")
    shader = where / "harness.comp"
    shader.write_text(HARNESS.format(source=source, call=call))
    result = subprocess.run([validator, str(shader)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


SPHERE = """#version 450
layout(local_size_x = 64) in;
layout(std430, binding = 0) readonly buffer Frames {{ vec4 frames[]; }};  // rows t, b, n per pixel
layout(std430, binding = 1) readonly buffer Wo {{ vec4 wo[]; }};
layout(std430, binding = 2) writeonly buffer Radiance {{ vec4 radiance[]; }};
uniform uint n;
uniform int lights;
uniform vec3 light_dir[8];   // world, towards the light
uniform vec3 irradiance[8];

{source}

void main() {{
    uint i = gl_GlobalInvocationID.x;
    if (i >= n) return;
    mat3 to_local = transpose(mat3(frames[3 * i].xyz, frames[3 * i + 1].xyz, frames[3 * i + 2].xyz));
    vec3 sum = vec3(0.0);
    for (int k = 0; k < lights; ++k) {{
        vec3 wi = to_local * light_dir[k];
        if (wi.z > 0.0) sum += neuenh_brdf(wi, wo[i].xyz) * wi.z * irradiance[k];
    }}
    radiance[i] = vec4(sum, 0.0);
}}
"""


def shade_sphere(ctx, source: str, frames: np.ndarray, wo: np.ndarray, lights: list[tuple]) -> np.ndarray:
    """Radiance of pixels with shading ``frames`` (P, 3, 3: rows t, b, n) seen from ``wo`` (P, 3,
    local) under directional ``lights`` [(direction, irradiance RGB)], shaded by the exported
    ``neuenh_brdf``: sum over lights of f_r(wi, wo) cos(theta_i) E."""
    n = len(frames)
    program = ctx.compute_shader(SPHERE.format(source=source))
    rows = np.concatenate([frames, np.zeros((n, 3, 1))], axis=2).astype(np.float32)
    pad = np.hstack([wo, np.zeros((n, 1))]).astype(np.float32)
    buffers = [ctx.buffer(rows.tobytes()), ctx.buffer(pad.tobytes()), ctx.buffer(reserve=16 * n)]
    try:
        for binding, buffer in enumerate(buffers):
            buffer.bind_to_storage_buffer(binding)
        program["n"], program["lights"] = n, len(lights)
        directions = [tuple(np.asarray(d, float) / np.linalg.norm(d)) for d, _ in lights]
        program["light_dir"].value = directions + [(0.0, 0.0, 1.0)] * (8 - len(lights))
        program["irradiance"].value = [tuple(e) for _, e in lights] + [(0.0, 0.0, 0.0)] * (8 - len(lights))
        program.run(group_x=(n + 63) // 64)
        return np.frombuffer(buffers[2].read(), dtype=np.float32).reshape(n, 4)[:, :3].astype(np.float64)
    finally:
        for buffer in buffers:
            buffer.release()
        program.release()
