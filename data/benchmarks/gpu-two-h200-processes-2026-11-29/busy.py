"""Cores and GPU busy over each run of a call folder, from its raw files.

usage: python3 busy.py CALL_FOLDER ...
Cores: vmstat's us + sy (of the machine's 32 cores) over the samples within the run's span of
stored steps (`bench run`'s "over S s"), counted back from the run's end in RUN-runs.log.
GPU busy: nvidia-smi's utilisation, mean over the samples while the GPU held more than 20 GB
(the model); the CSV has no index column: with two GPUs visible its lines alternate GPU 0, GPU 1.
"""
import datetime, os, re, statistics, sys

for folder in sys.argv[1:]:
    for run in ("one", "split", "two"):
        vmstat = os.path.join(folder, f"{run}-vmstat.txt")
        if not os.path.exists(vmstat):
            continue
        end = next(l for l in open(os.path.join(folder, f"{run}-runs.log")) if ": end " in l)
        end = datetime.datetime.strptime(end.split(": end ")[1][:19], "%Y-%m-%dT%H:%M:%S")
        span = float(re.search(r"over ([0-9.]+) s", open(os.path.join(folder, f"{run}.log")).read()).group(1))
        busy = []
        for line in open(vmstat):
            f = line.split()
            if not f or not f[0].isdigit():
                continue
            t = datetime.datetime.strptime(f[-2] + " " + f[-1], "%Y-%m-%d %H:%M:%S")
            if end - datetime.timedelta(seconds=span) <= t <= end:
                busy.append(int(f[12]) + int(f[13]))
        gpus = [[], []]
        for i, line in enumerate(open(os.path.join(folder, f"{run}-nvidia-smi.csv"))):
            f = [x.strip() for x in line.split(",")]
            util, mem = float(f[1].split()[0]), float(f[2].split()[0])
            if mem > 20000:
                gpus[i % 2].append(util)
        util = " / ".join(f"{statistics.mean(g):.1f}%" for g in gpus if g)
        print(f"{folder} {run}: {statistics.mean(busy) * 32 / 100:.1f} cores ({len(busy)} samples); GPU busy {util}")
