"""Regenerate the small foreign-layout examples in this folder (deterministic).

    python tests/data/foreign/make_foreign.py

* ``machining_center_b_small.xlsx`` - the layout of ``raw/machining-center-b``: sheet
  "Info" (text) and "Messdaten" (header in row 1: "Zeit [s]", "Drehzahl [1/min]",
  "Temperatur 1 [°C]".."Temperatur 16 [°C]", "Verlagerung X1/Y1/Z1/Z2 [µm]",
  "Bemerkung"), 15 s sampling, 240 rows. Z1 is the target and grows *negative*
  (sign -1 in the mapping).
* ``machining_center_b_small.csv`` - the same data as a German Excel CSV export:
  ';' delimiter, decimal commas, latin-1 encoded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
N = 240
PERIOD_S = 15

HEADER = (["Zeit [s]", "Drehzahl [1/min]"]
          + [f"Temperatur {i} [°C]" for i in range(1, 17)]
          + ["Verlagerung X1 [µm]", "Verlagerung Y1 [µm]", "Verlagerung Z1 [µm]",
             "Verlagerung Z2 [µm]", "Bemerkung"])


def table() -> list[list]:
    t = np.arange(N) * PERIOD_S
    speed = np.where(t < 2400, 6000.0, 0.0)
    heat = 1 - np.exp(-np.minimum(t, 2400) / 900.0)
    cool = np.where(t > 2400, np.exp(-(t - 2400) / 1200.0), 1.0)
    rows = []
    for k in range(N):
        temps = [round(21.5 + 0.1 * i + (2 + 0.5 * i) * heat[k] * cool[k]
                       + 0.02 * np.sin(0.3 * k + i), 2) for i in range(16)]
        z1 = round(-(18.0 * heat[k] * cool[k]) + 0.05 * np.sin(0.7 * k), 3)
        note = {0: "Start", 160: "Spindel aus", N - 1: "Ende"}.get(k)
        rows.append([int(t[k]), speed[k], *temps,
                     round(1.2 * heat[k] * cool[k], 3), round(-0.8 * heat[k] * cool[k], 3),
                     z1, round(0.9 * z1, 3), note])
    return rows


def write_xlsx(path: Path) -> None:
    import openpyxl

    wb = openpyxl.Workbook()
    info = wb.active
    info.title = "Info"
    info.append(["Maschine", "Bearbeitungszentrum B"])
    info.append(["Abtastzeit", "15 s"])
    info.append(["Hinweis", "Verlagerung Z1 positiv = Spindel vom Tisch weg"])
    ws = wb.create_sheet("Messdaten")
    ws.append(HEADER)
    for row in table():
        ws.append(row)
    wb.save(path)


def write_csv(path: Path) -> None:
    lines = [";".join(HEADER)]
    for row in table():
        cells = []
        for v in row:
            if v is None:
                cells.append("")
            elif isinstance(v, str):
                cells.append(v)
            else:
                cells.append(f"{v:g}".replace(".", ","))
        lines.append(";".join(cells))
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("latin-1"))


if __name__ == "__main__":
    write_xlsx(HERE / "machining_center_b_small.xlsx")
    write_csv(HERE / "machining_center_b_small.csv")
