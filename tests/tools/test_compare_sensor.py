"""tools/research/compare_sensor.py: the calibrated preset next to the real recording, as a table and a figure."""
import pytest


@pytest.mark.slow
def test_table_and_figure(tmp_path, real_recording, capsys, load_tool):
    tool = load_tool("research/compare_sensor.py")
    assert tool.main([str(real_recording), "--frames", "8", "--out", str(tmp_path / "fig.png")]) == 0
    rows = {line.split("|")[0].strip(): [cell.strip() for cell in line.split("|")[1:]]
            for line in capsys.readouterr().out.splitlines() if "|" in line}
    assert rows["pulses per frame"] == ["12312", "12312"]
    real_noise, sim_noise = (float(v) for v in rows["range noise sigma median [cm]"])
    assert 0.6 < real_noise < 1.0 and abs(sim_noise - real_noise) < 0.3
    real_dropout, sim_dropout = (float(v) for v in rows["no-return fraction [%]"])
    assert 5.0 < real_dropout < 6.0 and abs(sim_dropout - real_dropout) < 1.0
    assert (tmp_path / "fig.png").stat().st_size > 50_000
