"""Turn a run ``bgc simulate`` wrote into the file a plant's logger would
write, for the README's calibrate -> monitor example: Unix time stamps from
``START``, a ``# date:`` line, only the ``time``, ``u:`` and ``y:`` columns
(no true states), ten seconds with no row (rows 200 to 219: the logger was
down), an empty input cell (row 300) and an empty F12 cell (row 350).

    python docs/examples/logger_shaped.py SIMULATED.csv LOGGER.csv START DATE
"""

import csv
import sys


def main(src: str, dst: str, start: float, date: str) -> None:
    with open(src, encoding="utf-8") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("#")))
    head, body = rows[0], rows[1:]
    keep = [i for i, h in enumerate(head) if h == "time" or h.startswith(("u:", "y:"))]
    with open(dst, "x", newline="", encoding="utf-8") as f:  # never over an existing file
        f.write(f"# date: {date}\n# plant logger, tank farm B, flows in m^3/s\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow([head[i] for i in keep])
        for k, row in enumerate(body):
            if 200 <= k < 220:
                continue
            out = [row[i] for i in keep]
            out[0] = f"{start + float(row[0]):.1f}"
            if k == 300:
                out[head.index("u:f_in")] = ""
            if k == 350:
                out[[head[i] for i in keep].index("y:F12")] = ""
            w.writerow(out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4])
