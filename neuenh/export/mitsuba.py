"""Mitsuba 3 export: a fitted material as a ``neuenh`` BSDF plugin, written in Python with Dr.Jit.

    from neuenh.export import mitsuba as nm
    mi = nm.set_variant("llvm_ad_rgb")       # finds a libLLVM Dr.Jit can use (or scalar_rgb, cuda_ad_rgb)
    nm.register()                            # the plugin "neuenh"
    scene = mi.load_file("out/paper_white.xml")   # written by neuenh export --format mitsuba
    image = mi.render(scene)

``eval`` is the specialized evaluator (``neuenh.specialize``) run on Dr.Jit arrays: the same
backend-neutral formulas as the torch model (``neuenh.ops``; here ``DrJitOps``), the material's
shading frame as a constant rotation, the neural modules with the per-material inputs folded into
their first-layer biases — so it cannot drift from the model. Conventions: Mitsuba's local frame
is neuenh's (z the shading normal, x the tangent ``sh_frame.s`` before ``t_theta``); Mitsuba's
``si.wi`` points to the viewer and ``wo`` to the light, neuenh's ``wi`` is the light: the plugin
evaluates ``f_r(wi=wo_mitsuba, wo=si.wi)`` and returns it times the light's cosine, as Mitsuba's
own BSDFs do.

``sample``/``pdf`` draw the material's fitted analytical lobe, as the paper samples a refitted
analytical model: with probability ``p_spec`` (the specular albedo's share of the fitted albedos,
kept in [0.1, 0.9]) Mitsuba's visible-normal sampling of a GGX with the material's ``alpha_x,
alpha_y`` in its shading frame (``mi.MicrofacetDistribution``, Heitz 2018), else a cosine lobe.
The weight is ``eval / pdf``, so the estimator is unbiased whatever the lobe's fit.

Files (``write``): ``neuenh-model/`` (the model's bundle: module weights, no materials), per
material ``NAME.json`` (its parameters and the bundle's folder) and ``NAME.xml`` (the ball under the
studio environment map ``studio.exr``, a path tracer, the plugin with ``filename`` = ``NAME.json``).

``write_nbrdf``: per NBRDF network (a scene plan's ``nbrdf`` rung, ``neuenh.export.nbrdf``) ``NAME.json``
(format ``neuenh-mitsuba-nbrdf``: its weights and the lobe it is sampled with, no shading frame) and
``NAME.xml``; the same plugin reads either kind of ``NAME.json``.

Imports ``mitsuba`` only inside ``set_variant``, ``register`` and the plugin (the ``neuenh[export]``
extra). The LLVM variants JIT-compile with the system's libLLVM, which must be version 17 or newer
(Dr.Jit 1.5 emits ``llvm.minimum``/``maximum``, which LLVM 15 and 16 cannot select on x86 and abort
on): ``set_variant`` points ``DRJIT_LIBLLVM_PATH`` at the newest one installed when it is unset
(Debian 12: ``apt-get install libllvm19``; ``make mitsuba``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import torch

from ..files import atomic_write
from ..llvm import LLVM_MIN, find_libllvm, point_drjit_at_libllvm  # noqa: F401 (LLVM_MIN, find_libllvm: this module's API)
from ..materials import MaterialParams
from ..ops import DrJitArrayOps
from ..shading import shade
from ..specialize import unrolled_mlp, walk
from . import file_names

PLUGIN = "neuenh"
FORMAT = "neuenh-mitsuba-material"
NBRDF_FORMAT = "neuenh-mitsuba-nbrdf"  # an NBRDF network's material (write_nbrdf)
BUNDLE_DIR = "neuenh-model"
ENVMAP = "studio.exr"


def set_variant(variant: str = "llvm_ad_rgb"):
    """``mitsuba`` with ``variant`` set; for an LLVM variant ``DRJIT_LIBLLVM_PATH`` is pointed at
    ``find_libllvm()`` first, unless set. A RuntimeError says what to install when there is none."""
    if variant.startswith("llvm") and not point_drjit_at_libllvm():
        raise RuntimeError(f"Mitsuba's {variant} variant needs libLLVM {LLVM_MIN} or newer (Debian 12: "
                           "apt-get install libllvm19, or make mitsuba); or set DRJIT_LIBLLVM_PATH")
    import mitsuba as mi

    mi.set_variant(variant)
    return mi


# -- the ops vocabulary on Dr.Jit arrays --------------------------------------------------------------
class DrJitOps(DrJitArrayOps):
    """``neuenh.ops``' vocabulary on the active Mitsuba variant's Dr.Jit types: per-sample scalars are
    ``mi.Float``, RGB values ``mi.Color3f``, directions ``mi.Vector3f``; Python floats fold."""

    def __init__(self):
        import mitsuba as mi

        super().__init__(mi.Vector3f)
        self.mi = mi


# -- the material, evaluated ----------------------------------------------------------------------------
class DrJitMaterial:
    """A specialized material (``SpecializedBRDF``) evaluated on Dr.Jit arrays: ``f_r(wi, wo, active)``
    -> ``mi.Color3f`` without the cosine factor, neuenh's convention (``wi`` the light); zero where
    ``active`` is false or either direction is below either horizon.

    The formulas and modules run inside a conditional (``dr.if_stmt``) on that mask: in a kernel
    Dr.Jit compiles it symbolically (a branch taken by a SIMD packet, LLVM, or a warp, CUDA, when any
    of its lanes needs the value), so lanes whose value is zero anyway — an emitter sample below the
    surface, a dead path — do not pay for the modules' matrix products."""

    def __init__(self, special):
        self.xp = DrJitOps()
        mi = self.xp.mi
        k = special.folded.to(torch.float64)
        self.expression, self.folded = special.expression, k
        self.rotation = None if k.rotation is None else [[float(v) for v in row] for row in k.rotation.tolist()]
        self.params = {name: self._constant(v) for name, v in k.params.items()}
        self.constants = {name: self._constant(v) for name, v in k.constants.items()}
        self.modules = {name: m.as_floats() for name, m in k.modules.items()}
        self._mi = mi

    def _constant(self, value):
        if isinstance(value, float):
            return value
        flat = [float(v) for v in torch.as_tensor(value).reshape(-1).tolist()]
        if len(flat) == 1:
            return flat[0]
        return self.xp.mi.Color3f(*flat) if len(flat) == 3 else tuple(flat)

    def _rotate(self, w):
        return _rotate(self._mi, self.rotation, w)

    def _mlp(self, name: str, inputs: list):
        return _mlp(self.xp, self.modules[name], inputs)

    def _flat(self, value, width: int) -> list:
        if width == 1:
            return [value]
        if isinstance(value, self._mi.Color3f):
            return [value.x, value.y, value.z]
        return [value] * 3

    def __call__(self, wi, wo, active=True):
        mi, xp = self._mi, self.xp
        s = shade(xp, wi, wo, self._rotate(wi), self._rotate(wo), self.params)
        directions = [s.wi.x, s.wi.y, s.wi.z, s.wo.x, s.wo.y, s.wo.z]

        def module(expr, folded, operands):  # the seam where Dr.Jit runs an MLP
            if operands is None:  # a term's module reads the shading-frame directions
                return self._mlp(expr.name, directions)
            left, right = operands
            return self._mlp(expr.name, self._flat(left, expr.left.width) + self._flat(right, expr.right.width))

        def value():
            return mi.Color3f(walk(self.expression, self.folded, constant=lambda expr, v: self.constants[expr.name],
                                   formula=lambda term: term.formula(s), module=module))

        value = xp.dr.if_stmt((), active & s.above, value, lambda: mi.Color3f(0.0))
        return xp.dr.maximum(value, 0.0)


class DrJitNBRDF:
    """An NBRDF network (``neuenh.export.nbrdf``) on Dr.Jit arrays, called as ``DrJitMaterial`` is:
    ``f_r(wi, wo, active)`` -> ``mi.Color3f``, the network inside the same conditional."""

    def __init__(self, net):
        from .nbrdf import folded_network

        self.xp = DrJitOps()
        self.network = folded_network(net).to(torch.float64).as_floats()

    def __call__(self, wi, wo, active=True):
        from .nbrdf import above, brdf

        mi, xp = self.xp.mi, self.xp

        def value():
            return mi.Color3f(brdf(xp, wi, wo, lambda inputs: _mlp(xp, self.network, inputs)))

        return xp.dr.maximum(xp.dr.if_stmt((), active & above(wi, wo), value, lambda: mi.Color3f(0.0)), 0.0)


def _rotate(mi, rows: list | None, w, inverse: bool = False):
    """``w`` (``mi.Vector3f``) times the rotation whose ``rows`` are given (None: none), or its inverse
    (the transpose)."""
    if rows is None:
        return w
    (a, b, c), (d, e, f), (g, h, i) = rows
    if inverse:
        return mi.Vector3f(a * w.x + d * w.y + g * w.z, b * w.x + e * w.y + h * w.z, c * w.x + f * w.y + i * w.z)
    return mi.Vector3f(a * w.x + b * w.y + c * w.z, d * w.x + e * w.y + f * w.z, g * w.x + h * w.y + i * w.z)


def _mlp(xp: DrJitOps, module: tuple[list, list, float], inputs: list):
    """``unrolled_mlp`` on Mitsuba's types: a ``mi.Float`` for one output, else a ``mi.Color3f``."""
    x = unrolled_mlp(xp, module, inputs)
    return x[0] if len(x) == 1 else xp.mi.Color3f(*x)


# -- the plugin -------------------------------------------------------------------------------------------
def _read(path: Path, kind: str | None = None) -> dict:
    """An exported material file's JSON: of ``kind`` (``FORMAT``, ``NBRDF_FORMAT``) or, None, of either."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a neuenh Mitsuba material ({exc})") from None
    if not isinstance(data, dict) or data.get("format") not in (FORMAT, NBRDF_FORMAT):
        what = data.get("format") if isinstance(data, dict) else None
        raise ValueError(f"{path}: not a neuenh Mitsuba material (format {what!r})")
    if kind is not None and data["format"] != kind:
        raise ValueError(f"{path}: " + ("an NBRDF network's material (load_nbrdf reads it), not a model's" if kind == FORMAT
                                        else "a model's material (load_material reads it), not an NBRDF network's"))
    return data


def load_material(path: str | Path, data: dict | None = None):
    """(model, params) of an exported ``NAME.json`` (``write``); ``data``: its JSON, read already."""
    from ..checkpoint import Bundle

    path = Path(path)
    data = data if data is not None else _read(path, FORMAT)
    try:
        params = MaterialParams.from_json(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    bundle = Bundle.load(path.parent / data["bundle"])
    return bundle.model, params


def load_nbrdf(path: str | Path, data: dict | None = None):
    """(the network, (alpha, p_spec) of its sampling lobe) of an NBRDF material's ``NAME.json``
    (``write_nbrdf``); ``data``: its JSON, read already."""
    from ..study.nbrdf_fit import NBRDFNetwork

    path = Path(path)
    data = data if data is not None else _read(path, NBRDF_FORMAT)
    try:
        lobe = data["sampling"]
        return NBRDFNetwork.from_state(data["weights"]), (float(lobe["alpha"]), float(lobe["p_spec"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None


def _plugin_class():
    import drjit as dr
    import mitsuba as mi

    class NeuenhBSDF(mi.BSDF):
        """The ``neuenh`` BSDF (module doc). Properties: ``filename``, an exported ``NAME.json``."""

        def __init__(self, props):
            super().__init__(props)
            # relative to the scene file, as Mitsuba resolves every file a scene names
            self.filename = str(mi.file_resolver().resolve(str(props["filename"])))
            data = _read(Path(self.filename))  # either kind of material, read once
            if data["format"] == NBRDF_FORMAT:
                net, (ax, self.p_spec) = load_nbrdf(self.filename, data)
                self.material, ay, self.frame = DrJitNBRDF(net), ax, None
            else:
                model, params = load_material(self.filename, data)
                special = model.specialize(params)
                self.material = DrJitMaterial(special)
                values = {k: v.reshape(-1).tolist() for k, v in params.values.items()}
                ax = values.get("alpha_x", [0.5])[0]
                ay = values.get("alpha_y", [ax])[0]
                specular = sum(values.get("rho_s", [0.5])) / 3.0
                diffuse = sum(values.get("rho_d", [0.5])) / 3.0
                self.p_spec = min(max(specular / max(specular + diffuse, 1e-8), 0.1), 0.9)
                rotation = special.folded.rotation
                self.frame = None if rotation is None else [[float(v) for v in row] for row in rotation.tolist()]
            self.lobe = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, max(ax, 1e-4), max(ay, 1e-4), True)
            self.m_components = [mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide,
                                 mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide]
            self.m_flags = self.m_components[0] | self.m_components[1]

        # the material's shading frame (where its GGX lobe lives) and back
        def _to_shading(self, w):
            return _rotate(mi, self.frame, w)

        def _from_shading(self, w):
            return _rotate(mi, self.frame, w, inverse=True)

        def _pdf(self, wi, wo, active):
            """The lobe mixture's density of ``wo``; 0 where the material is (below either horizon,
            geometric or shading), so that every sample of positive density has a positive weight."""
            wi_s, wo_s = self._to_shading(wi), self._to_shading(wo)
            m = dr.normalize(wi_s + wo_s)
            glossy = self.lobe.pdf(wi_s, m) / (4.0 * dr.abs(dr.dot(wo_s, m)))
            glossy = dr.select(dr.dot(wo_s, m) > 0, glossy, 0.0)
            diffuse = mi.warp.square_to_cosine_hemisphere_pdf(wo)
            pdf = self.p_spec * glossy + (1.0 - self.p_spec) * diffuse
            above = (wi.z > 0) & (wo.z > 0) & (wi_s.z > 0) & (wo_s.z > 0)
            return dr.select(active & above, pdf, 0.0)

        def _value(self, si, wo, active):
            # neuenh's wi is the light: Mitsuba's wo; the material is zero below either horizon
            return self.material(wo, si.wi, active) * dr.maximum(wo.z, 0.0)

        def eval(self, ctx, si, wo, active=True):
            return self._value(si, wo, active)

        def pdf(self, ctx, si, wo, active=True):
            return self._pdf(si.wi, wo, active)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self._value(si, wo, active), self._pdf(si.wi, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            wi_s = self._to_shading(si.wi)
            m, _ = self.lobe.sample(wi_s, sample2)
            glossy_wo = self._from_shading(mi.reflect(wi_s, m))
            diffuse_wo = mi.warp.square_to_cosine_hemisphere(sample2)
            glossy = sample1 < self.p_spec
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = dr.select(glossy, glossy_wo, diffuse_wo)
            bs.pdf = self._pdf(si.wi, bs.wo, active)
            bs.eta = 1.0
            bs.sampled_type = dr.select(glossy, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                        mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
            bs.sampled_component = dr.select(glossy, mi.UInt32(0), mi.UInt32(1))
            ok = active & (si.wi.z > 0) & (bs.wo.z > 0) & (bs.pdf > 0)
            weight = self._value(si, bs.wo, ok) / dr.select(ok, bs.pdf, 1.0)
            return bs, dr.select(ok, weight, mi.Color3f(0.0))

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"NeuenhBSDF[filename={self.filename!r}, p_spec={self.p_spec:.3f}]"

    return NeuenhBSDF


def register() -> None:
    """Register the ``neuenh`` BSDF with Mitsuba (its variant must be set first)."""
    import mitsuba as mi

    if mi.variant() is None:
        raise RuntimeError("set a Mitsuba variant first, e.g. mi.set_variant('llvm_ad_rgb')")
    cls = _plugin_class()
    mi.register_bsdf(PLUGIN, lambda props: cls(props))


# -- files ------------------------------------------------------------------------------------------------
def write(model, materials: Mapping[str, MaterialParams], out_dir: Path) -> list[Path]:
    """The model's bundle, ``NAME.json`` and ``NAME.xml`` per material, and the environment map."""
    from ..checkpoint import Bundle
    from ..data.exr import write_rgb_exr
    from ..render.envmaps import studio_environment

    names = file_names(materials, ".json")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [Bundle(model).save(out_dir / BUNDLE_DIR), write_rgb_exr(out_dir / ENVMAP, studio_environment())]
    for name, material in names.items():
        record = MaterialParams.of(materials[material])
        model.specialize(record)  # a bad material fails here, before its files exist
        data = {"format": FORMAT, "version": 2, "material": material, "model": model.name, "state": model.state,
                "bundle": BUNDLE_DIR, **record.to_json()}
        written.append(atomic_write(out_dir / f"{name}.json", json.dumps(data, indent=1) + "\n"))
        written.append(atomic_write(out_dir / f"{name}.xml", scene_xml(f"{name}.json")))
    return written


def write_nbrdf(networks: Mapping[str, object], out_dir: Path) -> list[Path]:
    """``NAME.json`` (the network's weights and its sampling lobe, ``neuenh.export.nbrdf.sampling_lobe``)
    and ``NAME.xml`` per NBRDF network, and the environment map."""
    from ..data.exr import write_rgb_exr
    from ..render.envmaps import studio_environment
    from .nbrdf import sampling_lobe

    names = file_names(networks, ".json")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [write_rgb_exr(out_dir / ENVMAP, studio_environment())]
    for name, material in names.items():
        net = networks[material]
        alpha, p_spec = sampling_lobe(net)
        data = {"format": NBRDF_FORMAT, "version": 1, "material": material, "model": "nbrdf",
                "sampling": {"alpha": alpha, "p_spec": p_spec}, "weights": net.state()}
        written.append(atomic_write(out_dir / f"{name}.json", json.dumps(data) + "\n"))
        written.append(atomic_write(out_dir / f"{name}.xml", scene_xml(f"{name}.json")))
    return written


def scene_xml(material_file: str, size: int = 256, spp: int = 64) -> str:
    """The ball under the studio environment map, path traced, the plugin loading ``material_file``."""
    return f"""<scene version="3.0.0">
    <!-- neuenh export: the material on a sphere under the studio environment (neuenh.render.envmaps).
         Render after registering the plugin (docs/EXPORT.md): mi = neuenh.export.mitsuba.set_variant();
         neuenh.export.mitsuba.register(); mi.render(mi.load_file(this, spp=256, size=512)) -->
    <default name="spp" value="{spp}"/>
    <default name="size" value="{size}"/>
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 1.2, 4.2" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="$size"/><integer name="height" value="$size"/></film>
    </sensor>
    <emitter type="envmap"><string name="filename" value="{ENVMAP}"/></emitter>
    <shape type="sphere">
        <bsdf type="{PLUGIN}"><string name="filename" value="{material_file}"/></bsdf>
    </shape>
</scene>
"""
