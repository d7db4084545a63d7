"""GGX's positions and the paper's enhanced state, named once for every test."""

#: Sec. 4 of the paper: the nodes (terms) then the operators, in digit order of a state string.
GGX_POSITIONS = ("M", "S", "D", "F", "G", "invE", "S*D", "S*D*F", "S*D*F*G", "S*D*F*G*invE", "M+S*D*F*G*invE")

#: The paper's enhanced GGX, M + S·D·F̂ ×̂ Ĝ·(1/Ê) (Sec. 6): F, G, invE and the product x of
#: (S*D*F) x G neural.
PAPER_STATE = "00011100100"

#: GGX with alternative terms (``get_model("ggx", alternatives=True)``): Oren-Nayar at M, a Student-t D,
#: a conductor F, height-correlated G, and invE neural beside them.
ALTERNATIVES_STATE = "20422100000"


def small_ggx(state: str, seed: int):
    """GGX in ``state`` with (4, 8, 4) modules, for tests of the jit fit kernel (``neuenh.fit.jit``): its
    arithmetic is the same at every width, and a kernel's LLVM build grows about as the square of its
    operations, so on a new machine's empty ``~/.drjit`` (CI's) the default (16, 32, 16) modules' kernel
    with dense corrections builds for ~40 s and this one's in ~1 s (docs/BENCHMARKS.md, "Test suite
    time", stop 69)."""
    from neuenh.models import get_model
    from neuenh.modules import ModuleConfig

    return get_model("ggx", state=state, module_config=ModuleConfig(choices=((4, 8, 4),)), seed=seed)
