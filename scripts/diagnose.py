"""Why learned flocks crash at 20-50 UAVs: crash forensics and evaluation-time ablations of shipped
policies (a Hydra app on conf/diagnose.yaml; logic: flock_torchrl.report.diagnosis; findings:
docs/scaling.md).

    python scripts/diagnose.py                                    # the default grid, into outputs/diagnosis/
    python scripts/diagnose.py 'sizes=[20]' 'scenarios=[forest]' 'variants=[paper,instinct_off]' episodes=20
    python scripts/diagnose.py 'policies=[radial]' 'sizes=[20,50,100]' hydra.run.dir=outputs/diagnosis_radial

Each policy (a key of conf/diagnose.yaml's catalogue) pools its shipped seeds (episodes per seed and
cell). Writes rates.csv, crashes.csv and diagnosis.md into its output folder.
"""

from _start import start  # before anything heavy: Ctrl-C while torch loads is one line

if __name__ == "__main__":
    start("diagnose")
