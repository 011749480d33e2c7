from apphelpers import assert_clean


def test_home_renders_papers_and_sources(open_page):
    at = open_page()
    assert_clean(at)
    text = " ".join(m.value for m in at.markdown)
    for word in ("HAKF", "IRAKF", "NNMFUKF", "VB-EKF", "Where to start", "smartLoc", "rtkx"):
        assert word in text or word in " ".join(s.value for s in at.subheader), word
    assert at.title[0].value.startswith("navlab")
