"""Exporters: fitted materials of a model, in a renderer's own format (DESIGN §8).

Each format is a module with one entry point,

    write(model: BRDFModel, materials: Mapping[str, Mapping[str, Any]], out_dir: Path) -> list[Path]

that writes the files for ``materials`` (name -> the parameter dict ``BRDFModel.specialize``
takes: the analytical parameters and ``latent``, without a batch dimension) into ``out_dir`` and
returns their paths. What is exported is the specialized evaluator (``neuenh.specialize``): the
material's parameters and the modules' weights folded in, f_r without the cosine factor, zero below
either horizon. Every format is checked by running the artifact in its real runtime (tests):

* ``glsl``   (``neuenh.export.glsl``):    GLSL 4.50 functions, run on Mesa's llvmpipe;
* ``onnx``   (``neuenh.export.onnx``):    ONNX graphs, run with onnxruntime;
* ``mitsuba``(``neuenh.export.mitsuba``): a Mitsuba 3 BSDF plugin.

The runtimes are the optional extra ``neuenh[export]``; this package imports them only inside the
format that needs them. Imports neither Ray, FastAPI nor SQL.
"""

FORMATS = ("glsl", "onnx", "mitsuba")
