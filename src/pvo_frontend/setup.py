from glob import glob

from setuptools import find_packages, setup

package_name = "pvo_frontend"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/calibration", glob("calibration/*.yaml")),
        ("share/" + package_name + "/models/probe_kitti", glob("models/probe_kitti/*")),
        ("share/" + package_name + "/models/probe_sim", glob("models/probe_sim/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="pvo maintainers",
    maintainer_email="maintainers@pvo-project.org",
    description="Stereo visual odometry frontend of pvo",
    license="Apache-2.0",
    entry_points={"console_scripts": ["stereo_vo = pvo_frontend.stereo_vo_node:main"]},
)
