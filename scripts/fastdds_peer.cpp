// A ROS 2 peer on Fast DDS (eProsima Fast DDS 2.x, the middleware of rmw_fastrtps), without ROS: it publishes
// image files as sensor_msgs/msg/CompressedImage on rt/camera/image_raw/compressed, one at a time, and prints
// every lostx_msgs/msg/Place and geometry_msgs/msg/PoseWithCovarianceStamped lostx answers with, each message
// encoded and decoded with Fast CDR. DDS stays on the loopback interface. Built and run by check_fastdds.py:
//
//     fastdds_peer DOMAIN TIMEOUT_S IMAGE...      (prints "matched", then publishes once it reads "go")

#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/IPLocator.h>

#include <chrono>
#include <cstdint>
#include <fstream>
#include <iostream>
#include <iterator>
#include <memory>
#include <string>
#include <thread>
#include <vector>

using namespace eprosima::fastdds::dds;
using eprosima::fastcdr::Cdr;
using eprosima::fastcdr::FastBuffer;
using eprosima::fastrtps::rtps::InstanceHandle_t;
using eprosima::fastrtps::rtps::SerializedPayload_t;

// A sample is its CDR bytes, encapsulation header included; the messages are encoded and decoded around it.
struct Bytes {
  std::vector<char> data;
};

class BytesType : public TopicDataType {
 public:
  explicit BytesType(const std::string& name) {
    setName(name.c_str());
    m_typeSize = 64 * 1024 * 1024;
    m_isGetKeyDefined = false;
  }
  bool serialize(void* data, SerializedPayload_t* payload) override {
    auto* sample = static_cast<Bytes*>(data);
    if (sample->data.size() > payload->max_size) return false;
    std::copy(sample->data.begin(), sample->data.end(), payload->data);
    payload->length = static_cast<uint32_t>(sample->data.size());
    payload->encapsulation = CDR_LE;
    return true;
  }
  bool deserialize(SerializedPayload_t* payload, void* data) override {
    auto* sample = static_cast<Bytes*>(data);
    sample->data.assign(payload->data, payload->data + payload->length);
    return true;
  }
  std::function<uint32_t()> getSerializedSizeProvider(void* data) override {
    return [data]() { return static_cast<uint32_t>(static_cast<Bytes*>(data)->data.size()); };
  }
  void* createData() override { return new Bytes(); }
  void deleteData(void* data) override { delete static_cast<Bytes*>(data); }
  bool getKey(void*, InstanceHandle_t*, bool) override { return false; }
};

static Bytes compressed_image(int32_t sec, uint32_t nanosec, const std::vector<char>& png) {
  FastBuffer buffer;
  Cdr cdr(buffer, Cdr::LITTLE_ENDIANNESS, Cdr::DDS_CDR);
  cdr.serialize_encapsulation();
  cdr << sec << nanosec << std::string("camera_optical_frame");  // std_msgs/Header
  cdr << std::string("png");                                     // format
  cdr << static_cast<uint32_t>(png.size());                      // uint8[] data
  cdr.serializeArray(reinterpret_cast<const uint8_t*>(png.data()), png.size());
  Bytes out;
  out.data.assign(buffer.getBuffer(), buffer.getBuffer() + cdr.getSerializedDataLength());
  return out;
}

static void print_place(Bytes& sample) {
  FastBuffer buffer(sample.data.data(), sample.data.size());
  Cdr cdr(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
  cdr.read_encapsulation();
  int32_t sec, match_index;
  uint32_t nanosec;
  uint64_t frame;
  bool warming_up, has_position;
  double x, y, confidence;
  std::string frame_id, stream, state, error, match_name;
  cdr >> sec >> nanosec >> frame_id >> stream >> frame >> state >> warming_up >> error >> match_index >> match_name
      >> has_position >> x >> y >> confidence;
  std::cout << "place stamp=" << sec << "." << nanosec << " stream=" << stream << " frame=" << frame
            << " state=" << state << " match=" << match_index << " name=" << match_name
            << " confidence=" << confidence << std::endl;
}

static void print_pose(Bytes& sample) {
  FastBuffer buffer(sample.data.data(), sample.data.size());
  Cdr cdr(buffer, Cdr::DEFAULT_ENDIAN, Cdr::DDS_CDR);
  cdr.read_encapsulation();
  int32_t sec;
  uint32_t nanosec;
  std::string frame_id;
  double px, py, pz, qx, qy, qz, qw, covariance[36];
  cdr >> sec >> nanosec >> frame_id >> px >> py >> pz >> qx >> qy >> qz >> qw;
  cdr.deserializeArray(covariance, 36);
  std::cout << "pose stamp=" << sec << "." << nanosec << " frame_id=" << frame_id << " x=" << px << " y=" << py
            << " variance=" << covariance[0] << std::endl;
}

int main(int argc, char** argv) {
  if (argc < 4) {
    std::cerr << "usage: fastdds_peer DOMAIN TIMEOUT_S IMAGE..." << std::endl;
    return 2;
  }
  int domain = std::stoi(argv[1]);
  double timeout = std::stod(argv[2]);

  DomainParticipantQos pqos;
  pqos.name("lostx_fastdds_peer");
  auto udp = std::make_shared<eprosima::fastdds::rtps::UDPv4TransportDescriptor>();
  udp->interfaceWhiteList.push_back("127.0.0.1");  // this machine only
  pqos.transport().user_transports.push_back(udp);
  pqos.transport().use_builtin_transports = false;
  for (int index = 0; index < 32; ++index) {  // unicast discovery of the participants on localhost
    eprosima::fastrtps::rtps::Locator_t peer;
    eprosima::fastrtps::rtps::IPLocator::setIPv4(peer, 127, 0, 0, 1);
    peer.port = 7400 + 250 * domain + 10 + 2 * index;
    pqos.wire_protocol().builtin.initialPeersList.push_back(peer);
  }
  DomainParticipant* participant = DomainParticipantFactory::get_instance()->create_participant(domain, pqos);
  if (participant == nullptr) return 1;

  TypeSupport image_type(new BytesType("sensor_msgs::msg::dds_::CompressedImage_"));
  TypeSupport place_type(new BytesType("lostx_msgs::msg::dds_::Place_"));
  TypeSupport pose_type(new BytesType("geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"));
  image_type.register_type(participant);
  place_type.register_type(participant);
  pose_type.register_type(participant);
  Topic* images = participant->create_topic("rt/camera/image_raw/compressed", image_type.get_type_name(),
                                            TOPIC_QOS_DEFAULT);
  Topic* places = participant->create_topic("rt/lostx/place", place_type.get_type_name(), TOPIC_QOS_DEFAULT);
  Topic* poses = participant->create_topic("rt/lostx/pose", pose_type.get_type_name(), TOPIC_QOS_DEFAULT);

  DataWriterQos wqos = DATAWRITER_QOS_DEFAULT;
  wqos.reliability().kind = RELIABLE_RELIABILITY_QOS;
  wqos.history().kind = KEEP_LAST_HISTORY_QOS;
  wqos.history().depth = 10;
  DataReaderQos rqos = DATAREADER_QOS_DEFAULT;
  rqos.reliability().kind = RELIABLE_RELIABILITY_QOS;
  rqos.history().kind = KEEP_ALL_HISTORY_QOS;
  DataWriter* writer = participant->create_publisher(PUBLISHER_QOS_DEFAULT)->create_datawriter(images, wqos);
  Subscriber* subscriber = participant->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
  DataReader* place_reader = subscriber->create_datareader(places, rqos);
  DataReader* pose_reader = subscriber->create_datareader(poses, rqos);

  auto deadline = [timeout]() {
    return std::chrono::steady_clock::now() + std::chrono::milliseconds(static_cast<int64_t>(timeout * 1000));
  };
  auto until = deadline();
  PublicationMatchedStatus matched;
  do {
    writer->get_publication_matched_status(matched);
    if (std::chrono::steady_clock::now() > until) {
      std::cerr << "fastdds_peer: nothing subscribed to rt/camera/image_raw/compressed" << std::endl;
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  } while (matched.current_count == 0);
  // Matched here is not yet matched there: an image written before lostx has found this writer never reaches it.
  // The caller says when it has (lostx logs each publisher it finds).
  std::cout << "matched" << std::endl;
  std::string go;
  if (!std::getline(std::cin, go) || go != "go") return 1;

  Bytes sample;
  SampleInfo info;
  // The first message of a new Fast DDS writer does not always reach a Cyclone DDS reader (it can arrive before the
  // reader has the writer's first heartbeat, and is then taken for history). A probe goes first, again every 2 s
  // until it is answered; it is stamped far ahead, so that the first real frame, stamped earlier by years, starts
  // lostx's stream afresh (a clock that went back).
  std::ifstream first(argv[3], std::ios::binary);
  std::vector<char> probe_png((std::istreambuf_iterator<char>(first)), std::istreambuf_iterator<char>());
  Bytes probe = compressed_image(2000000000, 0, probe_png);
  int probes = 0;
  bool answered = false;
  until = deadline();
  while (!answered) {
    writer->write(&probe);
    ++probes;
    for (int tick = 0; tick < 400 && !answered; ++tick) {
      while (place_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) answered |= info.valid_data;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    if (std::chrono::steady_clock::now() > until) {
      std::cerr << "fastdds_peer: no answer to the probe" << std::endl;
      return 1;
    }
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // an answer to a second probe, if one was sent
  while (place_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {}
  while (pose_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {}
  std::cout << "probes " << probes << std::endl;

  int answers = 0;
  for (int k = 3; k < argc; ++k) {
    std::ifstream file(argv[k], std::ios::binary);
    std::vector<char> png((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
    Bytes message = compressed_image(1700000000 + (k - 3), 0, png);
    writer->write(&message);
    until = deadline();
    while (answers < k - 2) {  // one frame at a time: its answer before the next frame
      while (place_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
        if (info.valid_data) {
          print_place(sample);
          ++answers;
        }
      }
      while (pose_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
        if (info.valid_data) print_pose(sample);
      }
      if (std::chrono::steady_clock::now() > until) {
        std::cerr << "fastdds_peer: no answer to image " << (k - 2) << std::endl;
        return 1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  while (pose_reader->take_next_sample(&sample, &info) == ReturnCode_t::RETCODE_OK) {
    if (info.valid_data) print_pose(sample);
  }
  participant->delete_contained_entities();
  DomainParticipantFactory::get_instance()->delete_participant(participant);
  return 0;
}
