"""Raw read and write of a recording's joints.csv, for tests that edit recordings."""

import csv


def read_joints_csv(path):
    """(header, rows): rows as lists of floats, frame number first."""
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], [[float(v) for v in r] for r in rows[1:]]


def write_joints_csv(path, header, rows):
    """Write header and rows back, the frame number as an integer."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[int(r[0]), *r[1:]] for r in rows])
