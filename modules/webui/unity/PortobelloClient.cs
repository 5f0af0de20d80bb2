// A client of the Portobello webui bridge for Unity (or any .NET 4.x runtime): connects to
// ws://HOST:PORT/ws with the Foxglove WebSocket protocol (subprotocol foxglove.websocket.v1),
// subscribes to POSE_PREDICTED (or POSE) and AGENTS, and keeps the newest of each, already
// converted to Unity's frame. Receiving runs on a background task; Unity's main thread
// reads Latest* without waiting (no stalls of the main thread).
//
// Frames (docs/webui.md, "Unity"): the map is right-handed, z up; Unity is left-handed,
// y up. A point (x, y, z) in map is (x, z, y) in Unity; a rotation quaternion
// (w, x, y, z) in map is (x: -x, y: -z, z: -y, w: w) in Unity; a heading yaw
// (counter-clockwise from map +x) is a Unity rotation of -yaw about +Y.
//
// Compile and run (Debian mono): mcs -r:System.Runtime.Serialization.dll PortobelloClient.cs
//   mono PortobelloClient.exe ws://127.0.0.1:8080/ws [seconds]
using System;
using System.Collections.Generic;
using System.IO;
using System.Net.WebSockets;
using System.Runtime.Serialization;
using System.Runtime.Serialization.Json;
using System.Text;
using System.Threading;
using System.Threading.Tasks;

namespace Portobello
{
    // Unity's Vector3 / Quaternion layout, so the values drop straight into a Transform.
    public struct UVec3 { public double x, y, z; public override string ToString() { return string.Format("({0:F3}, {1:F3}, {2:F3})", x, y, z); } }
    public struct UQuat { public double x, y, z, w; public override string ToString() { return string.Format("({0:F4}, {1:F4}, {2:F4}, {3:F4})", x, y, z, w); } }

    public static class Frames
    {
        public static UVec3 Position(double[] p) { return new UVec3 { x = p[0], y = p[2], z = p[1] }; }
        public static UQuat Rotation(double[] q) { return new UQuat { x = -q[1], y = -q[3], z = -q[2], w = q[0] }; }
        // Unity euler Y (degrees) of a map heading.
        public static double HeadingY(double yawRad) { return -yawRad * 180.0 / Math.PI; }
    }

    [DataContract] public class Pose
    {
        [DataMember] public long utime;
        [DataMember] public double[] position;
        [DataMember] public double[] orientation;
        [DataMember] public double[] velocity;
        [DataMember] public int status;
    }
    [DataContract] public class Agent
    {
        [DataMember] public string id, kind, model, animation;
        [DataMember] public double[] position;
        [DataMember] public double yaw_rad;
        [DataMember] public double animation_phase;
        [DataMember] public bool in_render_range;
    }
    [DataContract] public class Agents
    {
        [DataMember] public long utime;
        [DataMember] public string scenario;
        [DataMember] public Agent[] agents;
    }
    [DataContract] class Channel { [DataMember] public int id; [DataMember] public string topic; }
    [DataContract] class ServerOp { [DataMember] public string op; [DataMember] public Channel[] channels; }

    public class UnityPose { public UVec3 position; public UQuat rotation; public long utime; public double ageS; }
    public class UnityAgent { public string id, kind, model, animation; public UVec3 position; public double headingY; public bool visible; }

    public class BridgeClient : IDisposable
    {
        readonly ClientWebSocket ws = new ClientWebSocket();
        readonly CancellationTokenSource stop = new CancellationTokenSource();
        readonly Dictionary<uint, string> subs = new Dictionary<uint, string>();
        uint nextSub = 1;
        public volatile UnityPose LatestPose;          // newest, replaced; read from any thread
        public volatile UnityAgent[] LatestAgents;
        public long Messages;

        public BridgeClient() { ws.Options.AddSubProtocol("foxglove.websocket.v1"); }

        public void Connect(Uri uri)
        {
            ws.ConnectAsync(uri, stop.Token).Wait();
            Task.Run(() => Receive());
        }

        static T Json<T>(byte[] data, int offset, int count)
        {
            return (T)new DataContractJsonSerializer(typeof(T)).ReadObject(new MemoryStream(data, offset, count));
        }

        void Send(string text)
        {
            var b = Encoding.UTF8.GetBytes(text);
            lock (ws) ws.SendAsync(new ArraySegment<byte>(b), WebSocketMessageType.Text, true, stop.Token).Wait();
        }

        async Task Receive()
        {
            var buf = new byte[1 << 16];
            var msg = new MemoryStream();
            while (!stop.IsCancellationRequested && ws.State == WebSocketState.Open)
            {
                WebSocketReceiveResult r;
                try { r = await ws.ReceiveAsync(new ArraySegment<byte>(buf), stop.Token); }
                catch (Exception) { break; }
                msg.Write(buf, 0, r.Count);
                if (!r.EndOfMessage) continue;
                byte[] data = msg.ToArray();
                msg.SetLength(0);
                if (r.MessageType == WebSocketMessageType.Text) OnText(data);
                else if (data.Length >= 13 && data[0] == 1) OnMessage(data);
            }
        }

        void OnText(byte[] data)
        {
            var op = Json<ServerOp>(data, 0, data.Length);
            if (op.op != "advertise" || op.channels == null) return;
            foreach (var ch in op.channels)
            {
                if (ch.topic != "POSE_PREDICTED" && ch.topic != "POSE" && ch.topic != "AGENTS") continue;
                uint id = nextSub++;
                subs[id] = ch.topic;
                Send("{\"op\":\"subscribe\",\"subscriptions\":[{\"id\":" + id + ",\"channelId\":" + ch.id + "}]}");
            }
        }

        const long UnixEpochTicks = 621355968000000000L;   // 1970-01-01 in DateTime ticks

        void OnMessage(byte[] data)
        {
            uint sub = BitConverter.ToUInt32(data, 1);
            ulong rxNs = BitConverter.ToUInt64(data, 5);
            string topic;
            if (!subs.TryGetValue(sub, out topic)) return;
            Interlocked.Increment(ref Messages);
            // in 100 ns ticks, not whole milliseconds: truncated to the millisecond, a
            // message received within the same millisecond had a negative age
            double age = ((DateTime.UtcNow.Ticks - UnixEpochTicks) * 100.0 - rxNs) / 1e9;
            if (topic == "AGENTS")
            {
                var m = Json<Agents>(data, 13, data.Length - 13);
                var list = new UnityAgent[m.agents.Length];
                for (int i = 0; i < list.Length; i++)
                {
                    var a = m.agents[i];
                    list[i] = new UnityAgent { id = a.id, kind = a.kind, model = a.model, animation = a.animation,
                        position = Frames.Position(a.position), headingY = Frames.HeadingY(a.yaw_rad), visible = a.in_render_range };
                }
                LatestAgents = list;
            }
            else if (topic == "POSE_PREDICTED" || LatestPose == null)   // POSE only until predicted poses come
            {
                var p = Json<Pose>(data, 13, data.Length - 13);
                LatestPose = new UnityPose { position = Frames.Position(p.position), rotation = Frames.Rotation(p.orientation), utime = p.utime, ageS = age };
            }
        }

        // Abort closes the socket, so a ReceiveAsync still pending ends now rather than holding the
        // process (mono waited on it at exit in about one run in fifty).
        public void Dispose() { stop.Cancel(); ws.Abort(); ws.Dispose(); }

        // A console run: prints what a Unity scene would place, once a second.
        public static int Main(string[] args)
        {
            if (args.Length < 1 || args[0] == "--help") { Console.WriteLine("usage: PortobelloClient.exe ws://HOST:PORT/ws [seconds]"); return args.Length < 1 ? 2 : 0; }
            int seconds = args.Length > 1 ? int.Parse(args[1]) : 5;
            using (var c = new BridgeClient())
            {
                c.Connect(new Uri(args[0]));
                for (int i = 0; i < seconds; i++)
                {
                    Thread.Sleep(1000);
                    var p = c.LatestPose;
                    var a = c.LatestAgents;
                    if (p != null) Console.WriteLine("pose utime={0} unity_position={1} unity_rotation={2} age_s={3:F3}", p.utime, p.position, p.rotation, p.ageS);
                    if (a != null) foreach (var g in a) Console.WriteLine("agent {0} {1} unity_position={2} heading_y={3:F2} anim={4} visible={5}", g.id, g.kind, g.position, g.headingY, g.animation, g.visible);
                }
                Console.WriteLine("messages={0}", Interlocked.Read(ref c.Messages));
            }
            return 0;
        }
    }
}
