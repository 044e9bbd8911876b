from glob import glob

from setuptools import find_packages, setup

package_name = "pvo_pseudosensors"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/models/sun_bcnn", glob("models/sun_bcnn/*")),
        ("share/" + package_name + "/models/sun_bcnn_kitti", glob("models/sun_bcnn_kitti/*")),
        ("share/" + package_name + "/models/hydranet", glob("models/hydranet/*")),
        ("share/" + package_name + "/models/hydranet_kitti", glob("models/hydranet_kitti/*")),
        ("share/" + package_name + "/models/dpc_net", glob("models/dpc_net/*")),
        ("share/" + package_name + "/models/dpc_net_clean", glob("models/dpc_net_clean/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pvo maintainers",
    maintainer_email="maintainers@pvo-project.org",
    description="Pseudo-sensors of pvo: the learning harness, Sun-BCNN, the simulated sun HydraNet, DPC-Net",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "simulated_sun = pvo_pseudosensors.simulated_sun_node:main",
            "sun_bcnn = pvo_pseudosensors.sun_bcnn_node:main",
            "hydranet = pvo_pseudosensors.hydranet_node:main",
            "dpc_net = pvo_pseudosensors.dpc_net_node:main",
        ]
    },
)
