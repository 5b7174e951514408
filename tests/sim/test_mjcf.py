def test_a_scene_recorded_under_another_install_is_the_same_model():
    from crowdteleop.sim.mjcf import same_model

    here = '<texture file="/work/main/.venv/lib/python3.11/site-packages/robosuite/a.png"/>'
    there = '<texture file="/opt/other/venv/lib/python3.12/site-packages/robosuite/a.png"/>'
    assert same_model(here, there)
    assert not same_model(here, there.replace("a.png", "b.png")), "another asset is another model"
    assert not same_model(here, here.replace("texture", "mesh")), "and so is another element"
