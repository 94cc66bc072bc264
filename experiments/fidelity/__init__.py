"""The fidelity studies: what the source documents claim, and what jaxdip finds under each reading of them.

Each study runs ``jaxdip run`` commands as child processes (``runs``) and writes a page and its JSON rows under
``docs/fidelity/``; ``index`` turns the claims inventory (``claims``), those rows and a folder of experiment runs
into ``docs/fidelity.md``. Run them from the repository root:

    python -m experiments.fidelity.lorenz_published_p   # docs/fidelity/lorenz.md, published_p.md
    python -m experiments.fidelity.dip                  # docs/fidelity/dip.md
    python -m experiments.fidelity.twip                 # docs/fidelity/twip.md, rwp.md
    python -m experiments.fidelity.index --runs DIR     # docs/fidelity.md
    python -m experiments.fidelity.integration_choice   # docs/integration.md
"""
