"""
hddpg-zoo: the experiment harness beside the sb3_hddpg library, as RL Zoo stands beside SB3 — the benchmark,
tuning studies, reports, the Ray executor, packaging and export of models, figures and recordings, the
quickstart and the MORL protocol. It imports the library only through its public names; the library never
imports it. Its own dependencies are the ``bench`` extra: ``pip install "sb3-hddpg[bench]"``.
"""
