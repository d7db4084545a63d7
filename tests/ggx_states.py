"""GGX's positions and the paper's enhanced state, named once for every test."""

#: Sec. 4 of the paper: the nodes (terms) then the operators, in digit order of a state string.
GGX_POSITIONS = ("M", "S", "D", "F", "G", "invE", "S*D", "S*D*F", "S*D*F*G", "S*D*F*G*invE", "M+S*D*F*G*invE")

#: The paper's enhanced GGX, M + S·D·F̂ ×̂ Ĝ·(1/Ê) (Sec. 6): F, G, invE and the product x of
#: (S*D*F) x G neural.
PAPER_STATE = "00011100100"

#: GGX with alternative terms (``get_model("ggx", alternatives=True)``): Oren-Nayar at M, a Student-t D,
#: a conductor F, height-correlated G, and invE neural beside them.
ALTERNATIVES_STATE = "20422100000"
