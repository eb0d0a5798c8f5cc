import numpy as np
import pytest
from illumon.observations import ObservationError, read_observations, write_observations


def test_round_trip_with_missing(tmp_path):
    p = tmp_path / "o.csv"
    p.write_text(
        "frame,time,patch,r,g,b\n"
        "a,2026-06-01T10:00:00Z,wall,100,120,90\n"
        "a,2026-06-01T10:00:00Z,road,50,55,60\n"
        "b,,wall,110,118,80\n"
    )
    obs = read_observations(p)
    assert obs.frames == ["a", "b"] and obs.patches == ["wall", "road"]
    assert np.isnan(obs.values[1, 1]).all()
    assert obs.values[0, 0, 1] == pytest.approx(120 / 255)
    q = tmp_path / "o2.csv"
    write_observations(q, obs)
    again = read_observations(q)
    assert np.allclose(np.nan_to_num(again.values), np.nan_to_num(obs.values))


@pytest.mark.parametrize(
    "body, message",
    [
        ("frame,patch,r,g,b\na,p,1,2,3\n", "missing column"),
        ("frame,time,patch,r,g,b\na,,p,1,x,3\n", r"row 2: column g: non-numeric"),
        ("frame,time,patch,r,g,b\na,,p,1,2,3\na,,p,1,2,3\n", "row 3: duplicate"),
        ("frame,time,patch,r,g,b\na,,p,1,-2,3\n", "negative"),
        ("frame,time,patch,r,g,b\na,yesterday,p,1,2,3\n", "ISO 8601"),
        ("frame,time,patch,r,g,b\na,,p,1,nan,3\n", "non-finite"),
    ],
)
def test_bad_observations(tmp_path, body, message):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ObservationError, match=message):
        read_observations(p)
